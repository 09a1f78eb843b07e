"""The shipped configs: every entry loads and builds its model; constructor defaults fill what they leave out; the schema,
the restricted literal parser and the ``--hyperparams`` overrides."""

from __future__ import annotations

import inspect

import pytest
import yaml

import envs
from sb3_eps.common.policies import DEFAULT_NET_ARCH, DEFAULT_STREAM_ARCH, MultiAgentQPolicy
from sb3_eps.eps import EPSSettings, EvolutionCallback, eps_env_id_for
from sb3_eps.zoo.config import (
    DEFAULT_KEY,
    ResolvedConfig,
    build_env,
    config_file,
    entry_yaml,
    load_config_entries,
    merged_entry,
    resolve_config,
)
from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.exp_manager import build_model
from sb3_eps.zoo.literal import parse_literal
from sb3_eps.zoo.schema import (
    ALGORITHM_PARAMS,
    ALGORITHMS,
    COMMAND_LINE_ARGUMENTS,
    EVOLUTION_CALLBACK,
    NAME_SPELLINGS,
    POLICY_KWARGS_KEY,
    RUN_PARAMS,
    algorithm_kwargs,
    algorithm_spec,
    build_callbacks,
    callback_class,
    package_defaults,
)

WORLD_ENV_IDS = [env_id for env_id in envs.ENV_IDS if env_id not in getattr(envs, "DEBUG_ENV_IDS", ())]
ENTRIES = [(algo, env_id) for algo in ALGORITHMS for env_id in WORLD_ENV_IDS]
# Keys an untuned entry may set: a budget, the world and EPS's settings chosen for a reason its notes give (the MPE
# entries' fitness), not the algorithm's hyper-parameters.
UNTUNED_KEYS = {"tuned", "notes", "n_timesteps", "n_envs", "env_kwargs", "callback"}
# ... and the layout chosen for wall-clock time under a time-to-solution rule, which the entry's notes must cite.
LAYOUT_KEYS = {"vec_env", "overlap_training", "batch_size"}


@pytest.mark.parametrize("algo", list(ALGORITHMS))
def test_every_world_has_an_explicitly_marked_entry(algo) -> None:
    entries = load_config_entries(config_file(algo), algo)
    assert DEFAULT_KEY in entries
    for env_id in WORLD_ENV_IDS:
        entry = entries[env_id]
        assert isinstance(entry.get("tuned"), bool), f"{algo}.yml: {env_id} must say tuned: true/false"
        if not entry["tuned"]:
            allowed = UNTUNED_KEYS | (LAYOUT_KEYS if "time_to_solution" in entry.get("notes", "") else set())
            assert set(entry) <= allowed, f"{algo}.yml: untuned {env_id} overrides {set(entry) - allowed}"


@pytest.mark.parametrize(("algo", "env_id"), ENTRIES, ids=[f"{a}-{e}" for a, e in ENTRIES])
def test_every_entry_builds_its_model(algo, env_id) -> None:
    path = config_file(algo)
    config = ResolvedConfig(algo, env_id, merged_entry(load_config_entries(path, algo), env_id, path), str(path))
    env = build_env(config, seed=0)
    try:
        model = build_model(config, env, seed=0, device="cpu", verbose=0)
        assert isinstance(model, ALGORITHMS[algo].algorithm_class)
        assert model.n_worlds == config.entry["n_envs"]
        callbacks = build_callbacks(config.entry, env_id, 0, str(path))
        assert [name for name, _ in callbacks] == ([EVOLUTION_CALLBACK] if ALGORITHMS[algo].eps else [])
        for _, callback in callbacks:
            assert callback.settings.eval_env_id == eps_env_id_for(env_id)
    finally:
        env.close()


@pytest.mark.parametrize("algo", list(ALGORITHMS))
def test_a_resolved_entry_holds_every_constructor_default(algo) -> None:
    """Config files list only what differs from the constructors; resolving fills in the rest from the signatures,
    so a run's config.yml lists every value (an entry that sets nothing builds the package-default model)."""
    spec = ALGORITHMS[algo]
    entry = resolve_config(algo, "MultiRobotNav-4-v0").entry
    signature = inspect.signature(spec.algorithm_class.__init__).parameters
    written = load_config_entries(config_file(algo), algo)
    set_by_file = {**written[DEFAULT_KEY], **written["MultiRobotNav-4-v0"]}
    for name in spec.params:
        default = signature[name].default
        if name not in set_by_file and default is not None:
            value = algorithm_kwargs(entry, spec)[name]
            assert value == default or (callable(default) and value(0.5) == default(0.5)), name  # lin_x: a schedule
    policy_kwargs = entry["policy_kwargs"]
    set_policy = set_by_file.get("policy_kwargs", {})  # a tuned entry may size its networks
    assert policy_kwargs["net_arch"] == set_policy.get("net_arch", DEFAULT_NET_ARCH)
    assert policy_kwargs["stream_arch"] == DEFAULT_STREAM_ARCH
    assert policy_kwargs["activation_fn"] == "nn.ReLU" and policy_kwargs["optimizer_class"] == "th.optim.Adam"
    assert policy_kwargs["agent_target"] is spec.algorithm_class.default_agent_target
    defaults = package_defaults(spec)["policy_kwargs"]
    assert all(
        policy_kwargs[key] == value for key, value in defaults.items() if key not in set_by_file.get("policy_kwargs", {})
    )
    if spec.eps:  # the EPS arguments the files list are the callback's defaults
        assert callback_class(EVOLUTION_CALLBACK) is EvolutionCallback
        parameters = inspect.signature(EPSSettings).parameters
        (item,) = written[DEFAULT_KEY]["callback"]
        assert all(value == parameters[name].default for name, value in item[EVOLUTION_CALLBACK].items())


def test_a_file_value_wins_over_the_constructor_default(tmp_path) -> None:
    path = tmp_path / "gdq.yml"
    path.write_text("default:\n  n_timesteps: 100\n  gamma: 0.5\n  policy_kwargs: {net_arch: [8]}\n")
    entry = resolve_config("gdq", "MultiRobotNav-4-v0", conf_file=path).entry
    assert entry["gamma"] == 0.5 and entry["n_steps"] == 3 and entry["learning_rate"] == "lin_0.0003"
    assert entry["global_bootstrap"] == 0.1  # GDQ-lambda 0.1, the package default since 2026-12-01
    assert entry["policy_kwargs"]["net_arch"] == [8] and entry["policy_kwargs"]["global_net_arch"] == [64, 64]
    assert list(entry)[:2] == ["n_timesteps", "learning_rate"]  # schema order, as config.yml writes it


def _parameters(cls: type) -> dict[str, object]:
    return {name: p.default for name, p in inspect.signature(cls.__init__).parameters.items()}


@pytest.mark.parametrize("algo", list(ALGORITHMS))
def test_schema_covers_every_constructor_argument(algo) -> None:
    spec = ALGORITHMS[algo]
    arguments = set(inspect.signature(spec.algorithm_class.__init__).parameters) - {"self"}
    assert arguments == set(spec.params) | set(COMMAND_LINE_ARGUMENTS) | {POLICY_KWARGS_KEY}
    policy_class = spec.algorithm_class.policy_aliases["MlpPolicy"]
    internal = {"self", "args", "kwargs", "observation_space", "action_space", "lr_schedule", "n_agents",
                "state_dim", "features_extractor_class", "features_extractor_kwargs"}  # fmt: skip
    accepted = set(_parameters(MultiAgentQPolicy)) | set(_parameters(policy_class))
    assert set(spec.policy_params) <= accepted - internal
    assert set(spec.policy_params) >= {
        "net_arch",
        "stream_arch",
        "activation_fn",
        "optimizer_class",
        "agent_target",
    }


def test_literal_parser_accepts_rl_zoo_strings() -> None:
    text = "dict(net_arch=[64, 64], activation_fn=nn.Tanh, optimizer_class=th.optim.AdamW, optimizer_kwargs=dict(eps=1e-5, betas=(0.9, 0.99)), x={'a': -1}, y=None)"
    assert parse_literal(text, NAME_SPELLINGS, "test") == {
        "net_arch": [64, 64],
        "activation_fn": "nn.Tanh",
        "optimizer_class": "th.optim.AdamW",
        "optimizer_kwargs": {"eps": 1e-5, "betas": [0.9, 0.99]},
        "x": {"a": -1},
        "y": None,
    }
    assert parse_literal("torch.nn.ReLU", NAME_SPELLINGS, "test") == "nn.ReLU"


@pytest.mark.parametrize(
    "text",
    [
        "__import__('os').system('true')",
        "dict(a=open('/etc/passwd'))",
        "dict(**{'a': 1})",
        "dict(a=nn.Module)",
        "dict(a=2**64**64)",
        "dict(a=[x for x in range(3)])",
        "dict(a=lambda: 0)",
        "nn.ReLU.__class__",
        "dict(a=os.system)",
        "dict(a=f'{1}')",
    ],
)
def test_literal_parser_refuses_code(text) -> None:
    with pytest.raises(ConfigError, match="is not allowed"):
        parse_literal(text, NAME_SPELLINGS, "test")


def test_hyperparams_override_and_round_trip(tmp_path) -> None:
    config = resolve_config(
        "eps_gdq",
        "CooperativeNavigation-v0",
        hyperparams=[
            "learning_rate:lin_1e-3",
            "train_freq:[2, episode]",
            "policy_kwargs.net_arch:[16]",
            "policy_kwargs:dict(net_arch=[32], activation_fn=nn.Tanh)",
            "callback.sigma:1e-2",
            "env_kwargs.max_cycles:10",
            "gamma:1e-1",
        ],
        n_timesteps=123,
    )
    entry = config.entry
    assert entry["learning_rate"] == "lin_1e-3" and entry["train_freq"] == [2, "episode"]
    assert entry["policy_kwargs"] == {"net_arch": [32], "activation_fn": "nn.Tanh"}  # a full mapping replaces
    assert entry["callback"][0][EVOLUTION_CALLBACK]["sigma"] == 0.01
    assert entry["callback"][0][EVOLUTION_CALLBACK]["population_size"] == 5  # the others stay (the default)
    assert entry["env_kwargs"] == {"max_cycles": 10} and entry["gamma"] == 0.1 and entry["n_timesteps"] == 123
    kwargs = algorithm_kwargs(entry, config.spec)
    assert kwargs["learning_rate"](1.0) == pytest.approx(1e-3) and kwargs["learning_rate"](0.5) == pytest.approx(5e-4)
    assert kwargs["train_freq"] == (2, "episode")
    # config.yml is read back by -conf into the same entry.
    path = tmp_path / "config.yml"
    path.write_text(entry_yaml(config.env_id, entry, "header"))
    assert load_config_entries(path, "eps_gdq")[config.env_id] == entry
    assert yaml.safe_load(path.read_text())[config.env_id]["policy_kwargs"]["activation_fn"] == "nn.Tanh"


def test_run_keys_and_algorithm_keys_do_not_overlap() -> None:
    assert not set(RUN_PARAMS) & set(ALGORITHM_PARAMS)


def test_weight_average_tau_in_a_config(tmp_path) -> None:
    """weight_average_tau is off by default but for GDQ and VDN (2e-4); a config may give a number in (0, 1] or null
    (no average, GDQ's too), nothing else."""
    assert "weight_average_tau" not in package_defaults(algorithm_spec("qmix"))["policy_kwargs"]
    assert package_defaults(algorithm_spec("gdq"))["policy_kwargs"]["weight_average_tau"] == 2e-4
    assert package_defaults(algorithm_spec("vdn"))["policy_kwargs"]["weight_average_tau"] == 2e-4
    assert package_defaults(algorithm_spec("vdn"))["advantage_learning"] == 0.5
    assert package_defaults(algorithm_spec("qmix"))["advantage_learning"] == 0.0
    gdq_path = tmp_path / "gdq.yml"
    gdq_path.write_text("default:\n  n_timesteps: 100\n  policy_kwargs: {weight_average_tau: null}\n")
    assert resolve_config("gdq", "MultiRobotNav-4-v0", conf_file=gdq_path).entry["policy_kwargs"]["weight_average_tau"] is None
    path = tmp_path / "vdn.yml"
    for value, expected in (("0.0005", 0.0005), ("null", None)):
        path.write_text(f"default:\n  n_timesteps: 100\n  policy_kwargs: {{weight_average_tau: {value}}}\n")
        entry = resolve_config("vdn", "MultiRobotNav-4-v0", conf_file=path).entry
        assert entry["policy_kwargs"]["weight_average_tau"] == expected
    for bad in ("0", "2", "often"):
        path.write_text(f"default:\n  n_timesteps: 100\n  policy_kwargs: {{weight_average_tau: {bad}}}\n")
        with pytest.raises(ConfigError, match="weight_average_tau must be"):
            resolve_config("vdn", "MultiRobotNav-4-v0", conf_file=path)


@pytest.mark.parametrize("algo", ["eps_iql", "eps_gdq"])
def test_the_mpe_eps_entries_select_by_return_with_a_min_gain(algo) -> None:
    """EPS in MPE selects by the paper's fitness (the return) with the entry's min_gain; the robots keep the default."""
    settings = {}
    for env_id in ("CooperativeNavigation-v0", "MultiRobotNav-4-v0"):
        entry = resolve_config(algo, env_id).entry
        ((_, callback),) = build_callbacks(entry, env_id, 0, algo)
        settings[env_id] = callback.settings
    assert (settings["CooperativeNavigation-v0"].fitness, settings["CooperativeNavigation-v0"].min_gain) == ("return", 0.2)
    assert (settings["MultiRobotNav-4-v0"].fitness, settings["MultiRobotNav-4-v0"].min_gain) == ("outcome", 0.05)
    # The MPE entry lists every EPS setting (a run's config.yml shows them all); the others are the default entry's.
    written = load_config_entries(config_file(algo), algo)
    ((name, mpe),) = written["CooperativeNavigation-v0"]["callback"][0].items()
    default = written[DEFAULT_KEY]["callback"][0][name]
    assert mpe == {**default, "fitness": "return", "min_gain": 0.2}
    # The command line overrides one item of the entry's callback.
    entry = resolve_config(algo, "CooperativeNavigation-v0", hyperparams=["callback.min_gain:0.5"]).entry
    ((_, callback),) = build_callbacks(entry, "CooperativeNavigation-v0", 0, algo)
    assert (callback.settings.fitness, callback.settings.min_gain) == ("return", 0.5)
