"""Malformed configs and flags: one clear line on stderr, exit status 2, no traceback, no run folder."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from sb3_eps import train
from sb3_eps.zoo.errors import run_command

GOOD = """\
CooperativeNavigation-v0:
  n_timesteps: 100
  n_envs: 1
"""

# (case id, YAML of -conf (None: the shipped file), extra flags, words the error line must contain)
CASES = [
    (
        "unknown-key",
        GOOD + "  learning_rat: 0.001\n",
        [],
        ["learning_rat", "bad.yml", "allowed keys", "learning_rate"],
    ),
    ("wrong-type", GOOD + "  batch_size: big\n", [], ["batch_size", "bad.yml", "an int >= 1"]),
    ("unknown-algo", None, ["--algo", "dqn"], ["--algo", "dqn", "gdq", "eps_gdq"]),
    ("unknown-env-flag", None, ["--env", "Foo-v0"], ["Foo-v0", "--env", "MultiRobotNav-4-v0"]),
    (
        "unknown-env-key",
        GOOD + "Foo-v0:\n  n_timesteps: 1\n",
        [],
        ["Foo-v0", "bad.yml", "allowed keys", "default"],
    ),
    (
        "unknown-activation",
        GOOD + '  policy_kwargs: "dict(activation_fn=nn.Foo)"\n',
        [],
        ["nn.Foo", "bad.yml", "policy_kwargs", "nn.ReLU"],
    ),
    (
        "import-string",
        GOOD + "  policy_kwargs: \"__import__('os').system('touch pwned')\"\n",
        [],
        ["__import__", "not allowed", "bad.yml"],
    ),
    ("negative-budget", GOOD.replace("100", "-5"), [], ["n_timesteps", "bad.yml", ">= 1"]),
    ("negative-n", None, ["-n", "-5"], ["-n", ">= 1"]),
    ("bad-schedule", GOOD + "  learning_rate: lin_abc\n", [], ["learning_rate", "lin_"]),
    ("bad-train-freq", GOOD + "  train_freq: [4, epoch]\n", [], ["train_freq", "one of step, episode"]),
    ("yaml-syntax", GOOD + "  gamma: [0.9\n", [], ["bad.yml", "not valid YAML"]),
    (
        "python-tag",
        GOOD + "  notes: !!python/object/apply:os.system ['touch pwned']\n",
        [],
        ["bad.yml", "python/object", "plain data"],
    ),
    ("not-a-mapping", "- CooperativeNavigation-v0\n", [], ["bad.yml", "must map env ids"]),
    (
        "unknown-callback",
        GOOD + "  callback: rl_zoo3.callbacks.ParallelTrainCallback\n",
        [],
        ["ParallelTrainCallback", "sb3_eps.EvolutionCallback"],
    ),
    (
        "eps-unknown-argument",
        GOOD + "  callback:\n    - sb3_eps.EvolutionCallback: {sigmaa: 0.1}\n",
        ["--algo", "eps_gdq"],
        ["sigmaa", "allowed", "sigma"],
    ),
    (
        "eps-bad-alpha",
        GOOD + "  callback:\n    - sb3_eps.EvolutionCallback: {alpha: 1.5}\n",
        ["--algo", "eps_gdq"],
        ["alpha", "[0, 1]"],
    ),
    ("eps-without-callback", GOOD, ["--algo", "eps_gdq"], ["eps_gdq", "sb3_eps.EvolutionCallback"]),
    ("hyperparams-no-colon", None, ["--hyperparams", "gamma"], ["--hyperparams", "key:value"]),
    ("hyperparams-unknown-key", None, ["--hyperparams", "gama:0.9"], ["--hyperparams", "gama", "gamma"]),
    ("gamma-out-of-range", GOOD + "  gamma: 1.5\n", [], ["gamma", "in [0, 1]"]),
    ("unknown-policy", GOOD + "  policy: CnnPolicy\n", [], ["policy", "MlpPolicy"]),
    ("env-kwargs-refused", GOOD + "  env_kwargs: {n_agents: 1}\n", [], ["env_kwargs", "n_agents"]),
    ("misspelt-default", "default_typo:\n  n_timesteps: 1\n", [], ["default_typo", "allowed keys"]),
    (
        "no-entry",
        "MultiRobotNav-2-v0:\n  n_timesteps: 1\n",
        [],
        ["no entry for 'CooperativeNavigation-v0'", "bad.yml"],
    ),
    ("n-envs-zero", GOOD.replace("n_envs: 1", "n_envs: 0"), [], ["n_envs", ">= 1"]),
    ("duplicate-key", GOOD + "  n_envs: 2\n", [], ["n_envs", "twice"]),
    ("missing-conf", "MISSING", [], ["does not exist", "-conf"]),
    ("resume-nowhere", None, ["--resume", "/nonexistent/run"], ["--resume", "not a run folder"]),
    ("init-from-missing", None, ["--init-from", "/nonexistent/model.zip"], ["--init-from", "not a file"]),
    (
        "eval-env-of-another-kind",
        GOOD,
        ["--eval-env", "MultiRobotNav-2-v0", "--eval-freq", "50"],
        ["--eval-env", "observation_space"],
    ),
]


def run_train(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    with pytest.raises(SystemExit) as exit_info:
        run_command(train.PROG, lambda: train.main(argv))
    return int(exit_info.value.code or 0), capsys.readouterr().err


@pytest.mark.parametrize(("case", "conf", "flags", "words"), CASES, ids=[case[0] for case in CASES])
def test_malformed_config_gives_one_line_and_exit_2(case, conf, flags, words, tmp_path, capsys) -> None:
    argv = ["--algo", "gdq", "--env", "CooperativeNavigation-v0", "-f", str(tmp_path / "logs"), "--seed", "0"]
    if conf is not None:
        path = tmp_path / "bad.yml"
        if conf != "MISSING":
            path.write_text(conf)
        argv += ["-conf", str(path)]
    status, stderr = run_train(argv + flags, capsys)
    assert status == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{train.PROG}: error: "), stderr
    for word in words:
        assert word in lines[0], f"{word!r} missing from: {lines[0]}"
    assert not (tmp_path / "logs").exists() or not any((tmp_path / "logs").rglob("*.yml"))
    assert not list((tmp_path / "logs").glob("*/*")) if (tmp_path / "logs").exists() else True
    assert not (tmp_path / "pwned").exists()


def test_a_real_process_prints_no_traceback(tmp_path) -> None:
    (tmp_path / "bad.yml").write_text(GOOD + "  batch_size: -3\n")
    command = [sys.executable, "-m", "sb3_eps.train", "--algo", "gdq", "--env", "CooperativeNavigation-v0"]
    command += ["-conf", str(tmp_path / "bad.yml"), "-f", str(tmp_path / "logs")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert result.stderr.strip() == textwrap.dedent(
        f"python -m sb3_eps.train: error: {tmp_path / 'bad.yml'}: entry 'CooperativeNavigation-v0': batch_size must "
        "be an int >= 1, got -3 (int)"
    )
    assert not (tmp_path / "logs").exists()
