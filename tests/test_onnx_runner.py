"""The exported policy without torch: ``export_policy``'s world description and ``sb3_eps/deploy/onnx_runner.py``.

(a) ONNX and torch pick the same greedy actions on 1,000 observations of each world (and shipped pretrained models
where ``sb3_eps.pretrained`` exists); (b) the runner imports and runs where torch cannot be imported; (c) the runner's
``observation`` rebuilt from a world's raw lidar ranges and target is the world's observation, to the bit; (d) the
JSON carries the world (``env_id``, ``env_kwargs``) and what a robot needs (beams, view, action table, decision
period); the example loop drives a world through the runner.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th

import envs
import sb3_eps
from envs.turtlebot3.robot import ACTION_ANGULAR, ACTION_LINEAR, BEAM_ANGLES, RANGE_MIN, WHEEL_SEPARATION
from sb3_eps import GDQ, export_policy, make_vec_env
from sb3_eps.deploy import OnnxPolicy

pytest.importorskip("onnxruntime")

ROOT = Path(__file__).resolve().parents[1]
RUNNER = ROOT / "sb3_eps" / "deploy" / "onnx_runner.py"
EXAMPLE = ROOT / "examples" / "onnx_runner_loop.py"
SHORT_VIEW = {"action_repeat": 4, "lidar_range": 1.0}
WORLDS = [
    ("MultiRobotNav-4-v0", SHORT_VIEW),
    ("MultiRobotNav-8-v0", SHORT_VIEW),
    ("MultiRobotNav-12-v0", SHORT_VIEW),
    ("MultiRobotNavUnseen-4-v0", {}),
    ("CooperativeNavigation-v0", {}),
]
N_OBS = 1000


class Exported:
    """A seeded GDQ of a world, its export and 1,000 observations of the world under random actions."""

    def __init__(self, env_id: str, env_kwargs: dict[str, Any], folder: Path) -> None:
        self.venv = make_vec_env(env_id, n_envs=1, seed=0, env_kwargs=env_kwargs)
        self.model = GDQ("MlpPolicy", self.venv, seed=0)
        # A fresh network picks two or three actions everywhere: weights spread wider make the arg max vary.
        generator = th.Generator().manual_seed(0)
        with th.no_grad():
            for weights in self.model.policy.greedy_net().parameters():
                weights.add_(0.2 * th.randn(weights.shape, generator=generator))
        self.onnx_path, self.json_path = export_policy(self.model, folder / "policy")
        self.description = json.loads(Path(self.json_path).read_text())
        self.policy = OnnxPolicy.load(self.json_path, threads=1)
        self.obs = collect_observations(self.venv)


def collect_observations(venv: Any, n: int = N_OBS) -> np.ndarray:
    """``n`` observations of the agents of a vec env whose worlds are stepped with random actions."""
    rng = np.random.default_rng(0)
    rows = [venv.reset().copy()]
    while sum(len(row) for row in rows) < n:
        obs, *_ = venv.step(rng.integers(0, venv.action_space.n, venv.num_envs))
        rows.append(obs.copy())
    return np.concatenate(rows)[:n].astype(np.float32)


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Any:
    cache: dict[str, Exported] = {}

    def get(env_id: str) -> Exported:
        if env_id not in cache:
            kwargs = dict(WORLDS)[env_id]
            cache[env_id] = Exported(env_id, kwargs, tmp_path_factory.mktemp(env_id))
        return cache[env_id]

    yield get
    for world in cache.values():
        world.venv.close()


def assert_same_greedy_actions(model: Any, policy: OnnxPolicy, obs: np.ndarray) -> None:
    with th.no_grad():
        torch_q = model.policy.greedy_net()(th.as_tensor(obs)).numpy()
    torch_actions = model.predict(obs, deterministic=True)[0]
    onnx_q, onnx_actions = policy.q_values(obs), policy.act(obs)
    np.testing.assert_allclose(onnx_q, torch_q, rtol=0, atol=1e-4)
    # Two actions whose Q-values tie to float precision may fall either way; every other arg max must be the same.
    top_two = np.sort(torch_q, axis=1)[:, -2:]
    clear = top_two[:, 1] - top_two[:, 0] > 1e-5
    assert clear.mean() > 0.99 and len(np.unique(torch_actions)) >= min(4, policy.n_actions - 1)
    np.testing.assert_array_equal(onnx_actions[clear], torch_actions[clear])
    assert onnx_actions.dtype == np.int64 and onnx_actions.shape == (len(obs),)
    assert policy.act(obs[0]) == int(np.argmax(onnx_q[0])) and policy.q_values(obs[0]).shape == (policy.n_actions,)


# ------------------------------------------------------------------------------------------ (a) ONNX = torch
@pytest.mark.parametrize("env_id", [env_id for env_id, _ in WORLDS])
def test_onnx_and_torch_pick_the_same_greedy_actions(env_id: str, exported: Any) -> None:
    world = exported(env_id)
    assert world.obs.shape == (N_OBS, world.policy.obs_dim)
    assert_same_greedy_actions(world.model, world.policy, world.obs)


@pytest.mark.parametrize("env_id", [env_id for env_id, _ in WORLDS])
def test_pretrained_models_pick_the_same_greedy_actions(env_id: str, tmp_path: Path) -> None:
    pretrained = getattr(sb3_eps, "pretrained", None)
    if pretrained is None:
        pytest.skip("sb3_eps.pretrained does not exist")
    try:
        model = pretrained("gdq", env_id)
    except (LookupError, ValueError, FileNotFoundError) as error:
        pytest.skip(f"no pretrained GDQ for {env_id}: {error}")
    # The world options the model needs (its card's), else this file's for the world.
    model_card = getattr(sb3_eps, "model_card", None)
    env_kwargs = model_card("gdq", env_id).env_kwargs if model_card is not None else dict(WORLDS)[env_id]
    venv = make_vec_env(env_id, n_envs=1, seed=0, env_kwargs=env_kwargs)
    try:
        _, json_path = export_policy(model, tmp_path / "pretrained", env=venv)
        obs = collect_observations(venv)
    finally:
        venv.close()
    policy = OnnxPolicy.load(json_path, threads=1)
    assert policy.env_id == env_id and policy.env_kwargs == env_kwargs
    assert_same_greedy_actions(model, policy, obs)


# ------------------------------------------------------------------------------------------ (b) without torch
def test_the_runner_runs_where_torch_cannot_be_imported(exported: Any, tmp_path: Path) -> None:
    world = exported("MultiRobotNav-4-v0")
    np.save(tmp_path / "obs.npy", world.obs)
    code = f"""
import importlib.util, json, sys
sys.modules["torch"] = None  # import torch raises ImportError from here on
spec = importlib.util.spec_from_file_location("onnx_runner", {str(RUNNER)!r})
runner = importlib.util.module_from_spec(spec)
spec.loader.exec_module(runner)
import numpy as np
try:
    import torch
except ImportError:
    pass
else:
    raise SystemExit("torch was importable")
policy = runner.OnnxPolicy.load({world.json_path!r}, threads=1)
obs = np.load({str(tmp_path / "obs.npy")!r})
rebuilt = policy.observation(np.full(28, 5.0), 2.0, 0.5)
print(json.dumps({{
    "actions": policy.act(obs).tolist(),
    "single": policy.act(obs[0]),
    "wheels": policy.wheel_velocities(17),
    "observation": rebuilt.tolist(),
    "modules": sorted(name for name, module in sys.modules.items() if module and name.split(".")[0] in ("torch", "sb3_eps", "envs")),
}}))
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    reply = json.loads(result.stdout)
    np.testing.assert_array_equal(reply["actions"], world.policy.act(world.obs))
    assert reply["single"] == world.policy.act(world.obs[0])
    assert reply["wheels"] == [0.21, 0.0]
    assert reply["observation"][:28] == [1.0] * 28 and reply["observation"][28:] == pytest.approx([0.2, 0.5 / np.pi])
    assert reply["modules"] == []


# ------------------------------------------------------------------------------------------ (c) the world's observation
def raw_target(env: Any, index: int) -> tuple[float, float]:
    """Robot ``index``'s target as the world measured it: distance [m] and bearing [rad] (wrapped)."""
    offset = env._targets[[index]] - env.world.xy[[index]]
    return float(env._distance[index]), float(env._bearing(np.array([index]), offset)[0])


@pytest.mark.parametrize("env_id", ["MultiRobotNav-4-v0", "MultiRobotNavUnseen-4-v0"])
def test_the_observation_rebuilt_from_raw_ranges_is_the_worlds(env_id: str, exported: Any) -> None:
    policy = exported(env_id).policy
    env = envs.make_parallel_env(env_id, **(policy.env_kwargs or {}))
    rng = np.random.default_rng(1)
    checked = 0
    try:
        observations, _ = env.reset(seed=3)
        for _ in range(40):
            indices = [env.possible_agents.index(agent) for agent in observations]
            targets = np.array([raw_target(env, i) for i in indices])
            rebuilt = policy.observation(env._scan_ranges[indices], targets[:, 0], targets[:, 1])
            np.testing.assert_array_equal(rebuilt, np.stack(list(observations.values())))
            one = policy.observation(env._scan_ranges[indices[0]], *targets[0])
            np.testing.assert_array_equal(one, observations[env.possible_agents[indices[0]]])
            # A heading not yet wrapped is wrapped first.
            turned = policy.observation(env._scan_ranges[indices], targets[:, 0], targets[:, 1] + 4 * np.pi)
            np.testing.assert_allclose(turned, rebuilt, atol=1e-6)
            checked += len(indices)
            if env.agents:
                observations, *_ = env.step({agent: int(rng.integers(20)) for agent in env.agents})
            else:
                observations, _ = env.reset()
    finally:
        env.close()
    assert checked >= 40
    lidar_range = policy.deployment["lidar"]["lidar_range_m"]
    assert lidar_range == policy.env_kwargs.get("lidar_range", 3.5)
    # No return (inf) reads the view's end; a reading under the minimum range reads the minimum.
    scan = policy.observation([np.inf] * 27 + [0.0], 20.0, -np.pi)
    assert scan[:27].tolist() == [1.0] * 27 and scan[27] == pytest.approx(RANGE_MIN / lidar_range)
    assert scan[28] == 1.0 and scan[29] == -1.0


def test_stacked_scans_are_rebuilt_from_the_earlier_raw_ranges() -> None:
    env = envs.make_parallel_env("MultiRobotNav-2-v0", lidar_frames=3, lidar_frame_ticks=2, lidar_range=2.0)
    description = json.loads(json.dumps({"deployment": env.deployment_description()}))  # as the JSON carries it
    description.update(input={"name": "obs", "shape": ["batch", 86]}, output={"name": "q_values"}, n_actions=20)
    policy = OnnxPolicy(None, description)  # no network: observation() needs the description only
    rng = np.random.default_rng(2)
    try:
        observations, _ = env.reset(seed=0)
        scans = [env._scan_ranges.copy()] * 5  # at the start, the earlier scans repeat the first one
        for _ in range(12):
            if not env.agents:
                break
            for agent, obs in observations.items():
                i = env.possible_agents.index(agent)
                earlier = np.stack([scans[-3][i], scans[-5][i]])  # 2 and 4 ticks ago, newest first
                rebuilt = policy.observation(scans[-1][i], *raw_target(env, i), earlier_ranges=earlier)
                np.testing.assert_array_equal(rebuilt, obs)
            observations, *_ = env.step({agent: int(rng.integers(20)) for agent in env.agents})
            scans.append(env._scan_ranges.copy())
    finally:
        env.close()
    with pytest.raises(ValueError, match="earlier_ranges"):
        policy.observation(np.ones(28), 1.0, 0.0)


# ------------------------------------------------------------------------------------------ (d) the JSON
def test_the_json_carries_the_world_and_the_robots_needs(exported: Any) -> None:
    description = exported("MultiRobotNav-12-v0").description
    assert description["env_id"] == "MultiRobotNav-12-v0" and description["env_kwargs"] == SHORT_VIEW
    deployment = description["deployment"]
    assert deployment["kind"] == "turtlebot3" and deployment["action_repeat"] == 4 and deployment["tick_s"] == 0.05
    assert deployment["decision_period_s"] == pytest.approx(0.2)
    lidar = deployment["lidar"]
    assert lidar["n_beams"] == 28 and lidar["angles_rad"] == BEAM_ANGLES.tolist()
    assert (lidar["lidar_range_m"], lidar["range_min_m"], lidar["range_max_m"]) == (1.0, 0.12, 3.5)
    assert deployment["observation"]["size"] == description["obs_dim"] == 30
    assert deployment["observation"]["goal_distance"]["scale_m"] == 10.0
    actions = deployment["actions"]
    assert actions["linear_m_s"] == ACTION_LINEAR.tolist() and actions["angular_rad_s"] == ACTION_ANGULAR.tolist()
    assert deployment["wheels"]["separation_m"] == WHEEL_SEPARATION == 0.16
    default_view = exported("MultiRobotNavUnseen-4-v0").description
    assert default_view["env_kwargs"] == {} and default_view["deployment"]["lidar"]["lidar_range_m"] == 3.5
    mpe = exported("CooperativeNavigation-v0").description
    assert (mpe["env_id"], mpe["n_actions"], mpe["obs_dim"], mpe["deployment"]) == ("CooperativeNavigation-v0", 5, 18, None)


def test_export_arguments(exported: Any, tmp_path: Path) -> None:
    world = exported("MultiRobotNav-4-v0")
    model = world.model
    _, old_style = export_policy(model, tmp_path / "old", 17)  # the former call: the model's own env is read
    assert json.loads(Path(old_style).read_text())["deployment"] == world.description["deployment"]
    with pytest.raises(ValueError, match="contradicts the env"):
        export_policy(model, tmp_path / "bad", env_id="MultiRobotNav-8-v0")
    with pytest.raises(ValueError, match=r"lidar_range=3\.5 contradict"):
        export_policy(model, tmp_path / "bad", env_kwargs={"lidar_range": 3.5})
    stacked = envs.make_parallel_env("MultiRobotNav-4-v0", lidar_frames=2)
    with pytest.raises(ValueError, match="58 floats"):
        export_policy(model, tmp_path / "bad", env=stacked)
    stacked.close()
    assert not list(tmp_path.glob("bad*"))
    # Without an env: a world of the id is built and read; a gymnasium world describes itself too.
    model.env = None
    try:
        _, by_id = export_policy(model, tmp_path / "by_id", env_id="SingleRobotNav-v0", env_kwargs=SHORT_VIEW)
        _, plain = export_policy(model, tmp_path / "plain")
    finally:
        model.env = world.venv
    by_id_description = json.loads(Path(by_id).read_text())
    assert by_id_description["env_id"] == "SingleRobotNav-v0" and by_id_description["env_kwargs"] == SHORT_VIEW
    assert by_id_description["deployment"] == world.description["deployment"]
    assert {key: json.loads(Path(plain).read_text())[key] for key in ("env_id", "env_kwargs", "deployment")} == dict.fromkeys(
        ("env_id", "env_kwargs", "deployment")
    )


# ------------------------------------------------------------------------------------------ the runner's API
def test_wheel_commands_and_one_line_errors(exported: Any, tmp_path: Path) -> None:
    policy = exported("MultiRobotNav-4-v0").policy
    linear, angular = policy.wheel_velocities(np.arange(20))
    np.testing.assert_array_equal(linear, ACTION_LINEAR)
    np.testing.assert_array_equal(angular, ACTION_ANGULAR)
    assert policy.wheel_velocities(2) == (0.0, 0.0) and policy.action_repeat == 4
    left, right = policy.wheel_speeds(19)
    assert (left, right) == pytest.approx((0.21 - np.pi / 2 * 0.08, 0.21 + np.pi / 2 * 0.08))
    assert policy.wheel_speeds(17, unit="rad/s") == pytest.approx((0.21 / 0.033, 0.21 / 0.033))
    actions = policy.act({"robot_1": np.zeros(30), "robot_0": np.ones(30)})
    assert list(actions) == ["robot_1", "robot_0"] and all(isinstance(a, int) for a in actions.values())
    mpe = exported("CooperativeNavigation-v0").policy
    (tmp_path / "broken.json").write_text(json.dumps({"format": "sb3-eps-policy", "onnx_file": "gone.onnx"}))
    failures = [
        (lambda: OnnxPolicy.load(tmp_path / "missing"), "no exported policy"),
        (lambda: OnnxPolicy.load(tmp_path / "broken.onnx"), "does not exist"),
        (lambda: policy.act(np.zeros(29)), r"shape \(30,\) or \(batch, 30\)"),
        (lambda: policy.act(np.zeros((2, 3, 30))), "shape"),
        (lambda: policy.q_values(np.full(30, np.nan)), "NaN"),
        (lambda: policy.observation(np.ones(27), 1.0, 0.0), "ranges must have shape"),
        (lambda: policy.observation(np.ones((2, 28)), [1.0], [0.0, 0.0]), "goal_distance must have shape"),
        (lambda: policy.observation(np.ones(28), -1.0, 0.0), ">= 0"),
        (lambda: policy.wheel_velocities(20), r"int in \[0, 19\]"),
        (lambda: policy.wheel_speeds(1, unit="rpm"), "unit"),
        (lambda: mpe.observation(np.ones(28), 1.0, 0.0), "TurtleBot3"),
        (lambda: mpe.wheel_velocities(1), "TurtleBot3"),
    ]
    for call, match in failures:
        with pytest.raises(ValueError, match=match) as error:
            call()
        assert "\n" not in str(error.value)


# ------------------------------------------------------------------------------------------ the example loop
def test_the_example_loop_drives_a_world_without_torch(exported: Any) -> None:
    world = exported("MultiRobotNav-4-v0")
    code = f"""
import runpy, sys
sys.modules["torch"] = None
sys.argv = ["onnx_runner_loop.py", {world.json_path!r}, "--max-steps", "5", "--episodes", "2"]
try:
    runpy.run_path({str(EXAMPLE)!r}, run_name="__main__")
finally:
    print("modules", sorted(name for name, module in sys.modules.items() if module and name.split(".")[0] in ("torch", "sb3_eps")))
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith("OnnxPolicy(GDQ, env_id='MultiRobotNav-4-v0'") and "held 0.20 s" in lines[1]
    assert lines[-2] == "success: 0/2 episodes" and lines[-1] == "modules []"
    assert sum(line.endswith("5 decisions") for line in lines) == 2


def test_the_safety_layer_on_the_robot_picks_what_the_evaluated_layer_picks(exported: Any) -> None:
    from research.lidar_shield import LidarShield

    world = exported("MultiRobotNav-8-v0")
    obs = world.obs.copy()
    obs[::3, 10:18] = 0.15  # a wall 0.15 m away in front of every third robot: the layer has work to do
    shield = LidarShield(world.model, lidar_range=1.0, action_repeat=4, margin=0.03)
    evaluated, _ = shield.predict(obs)
    on_robot = world.policy.act(obs, safety_margin=0.03)
    q_values = world.policy.q_values(obs)
    clearance = world.policy.clearance(obs)
    safe = clearance > 0.03
    # Where the safe actions' two best Q-values do not tie to float precision, both layers pick the same action.
    top_two = np.sort(np.where(safe, q_values, -np.inf), axis=1)[:, -2:]
    clear = (top_two[:, 1] - top_two[:, 0] > 1e-5) | ~safe.any(axis=1)
    assert clear.mean() > 0.99
    np.testing.assert_array_equal(on_robot[clear], evaluated[clear])
    assert shield.n_changed > 50  # the layer overrode the greedy action on many of the walled rows
    assert np.all(safe[np.arange(len(obs)), on_robot] | ~safe.any(axis=1))  # only safe actions, where one exists
    assert world.policy.act(obs[0], safety_margin=0.03) == on_robot[0]
    with pytest.raises(ValueError, match="safety_margin"):
        world.policy.act(obs, safety_margin=-0.1)
    with pytest.raises(ValueError, match="TurtleBot3"):
        exported("CooperativeNavigation-v0").policy.act(exported("CooperativeNavigation-v0").obs, safety_margin=0.03)
