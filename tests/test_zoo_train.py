"""A tiny real run through the command lines: the run folder, evaluate, plot, benchmark, warm start."""

from __future__ import annotations

import json
import pathlib

import numpy as np
import pytest
import torch as th
import yaml
from stable_baselines3.common.save_util import load_from_zip_file

from research import benchmark
from sb3_eps import evaluate, plot, train
from sb3_eps.zoo.config import load_config_entries
from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.run_folder import read_evaluation_world, read_monitor

ENV_ID = "CooperativeNavigation-v0"
ROOT = pathlib.Path(__file__).resolve().parents[1]
TINY = [
    "policy_kwargs:dict(net_arch=[16], stream_arch=[16], global_net_arch=[16])",
    "learning_starts:150",
    "batch_size:16",
    "buffer_size:2000",
    "n_envs:2",
]


def train_args(folder, *extra: str, algo: str = "gdq", env_id: str = ENV_ID, n: int = 1500) -> list[str]:
    return ["--algo", algo, "--env", env_id, "-n", str(n), "--seed", "0", "-f", str(folder), "--verbose", "0",
            "--eval-freq", "500", "--eval-episodes", "2", "--n-eval-envs", "1", "--save-freq", "500", *extra]  # fmt: skip


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("logs")
    assert train.main(train_args(folder, "--hyperparams", *TINY)) == 0
    (path,) = (folder / "gdq").iterdir()
    return path


def test_run_folder_follows_the_zoo_layout(run_dir) -> None:
    assert run_dir.name == f"{ENV_ID}_1"
    names = {path.name for path in run_dir.iterdir()}
    expected = {"progress.csv", "monitor.csv", "evaluations.npz", "best_model.zip", ENV_ID}
    assert expected | {f"{ENV_ID}.zip"} <= names
    assert "checkpoint.zip" not in names  # removed once the run finished
    assert not [name for name in names if name.endswith(".tmp")]
    # RL Zoo's parameter folder <run>/<env id>/: args.yml, config.yml, command.txt.
    params = run_dir / ENV_ID
    assert {path.name for path in params.iterdir()} == {"args.yml", "config.yml", "command.txt"}
    args = yaml.safe_load((params / "args.yml").read_text())
    assert args["algo"] == "gdq" and args["seed"] == 0 and args["n_timesteps"] == 1500
    assert "--hyperparams" in (params / "command.txt").read_text()
    # config.yml is a ready-to-use entry: -conf reads it back.
    entry = load_config_entries(params / "config.yml", "gdq")[ENV_ID]
    assert entry["policy_kwargs"]["net_arch"] == [16] and entry["n_envs"] == 2
    evaluations = np.load(run_dir / "evaluations.npz")
    assert list(evaluations["timesteps"][:3]) == [504, 1002, 1500]
    assert evaluations["results"].shape[1] == 2 and "successes" in evaluations and "ticks" in evaluations
    # The world the evaluations were measured on.
    world = {"env_id": ENV_ID, "env_kwargs": {}, "level_set": None, "n_episodes": 2}
    assert read_evaluation_world(run_dir) == world
    header, columns = read_monitor(run_dir / "monitor.csv")
    assert header["env_id"] == ENV_ID and header["n_agents"] == 3
    assert np.all(columns["l"] == 25) and np.all(np.diff(columns["ticks"]) >= 0)  # one row per world episode
    # SB3's own reader (and so RL Zoo's monitor-based plots) reads the run folder.
    from stable_baselines3.common.monitor import load_results

    frame = load_results(str(run_dir))
    assert len(frame) == len(columns["r"]) and {"r", "l", "t"} <= set(frame.columns)
    # SB3's keys (EvalCallback's eval/mean_reward, eval/mean_ep_length), the team ones as extras, no duplicates.
    from research.results import read_progress

    progress = read_progress(run_dir / "progress.csv")
    sb3_keys = {"eval/mean_reward", "eval/mean_ep_length", "rollout/ep_rew_mean", "rollout/ep_len_mean"}
    assert sb3_keys | {"eval/success_rate", "eval/std_reward", "time/ticks"} <= set(progress)
    assert not {"eval/team_return", "eval/length", "rollout/team_return"} & set(progress)
    rows = np.isfinite(progress["eval/mean_reward"])
    assert rows.sum() == 3 and np.allclose(progress["eval/mean_reward"][rows], evaluations["results"].mean(axis=1))
    assert np.allclose(progress["eval/mean_ep_length"][rows], evaluations["ep_lengths"].mean(axis=1))


def test_numbered_model_snapshots_on_save_freq(run_dir, tmp_path, capsys) -> None:
    """RL Zoo's rl_model_<timesteps>_steps.zip at every --save-freq (500 here), models that GDQ.load opens and that
    evaluate's --load-checkpoint / --load-last-checkpoint pick (as rl_zoo3.enjoy's flags)."""
    from sb3_eps import GDQ
    from sb3_eps.zoo.run_folder import snapshots

    found = snapshots(run_dir)
    assert list(found) == [504, 1002]
    model = GDQ.load(found[1002])
    assert model.num_timesteps == 1002
    output = tmp_path / "eval.json"
    assert evaluate.main(["--run", str(run_dir), "-n", "2", "--n-envs", "1", "--load-checkpoint", "504",
                          "--output", str(output)]) == 0  # fmt: skip
    assert json.loads(output.read_text())["model"].endswith("rl_model_504_steps.zip")
    assert evaluate.main(["--run", str(run_dir), "-n", "2", "--n-envs", "1", "--load-last-checkpoint"]) == 0
    assert (run_dir / "eval_CooperativeNavigation-v0_last.json").is_file()
    with pytest.raises(ConfigError, match=r"no rl_model_7_steps.zip \(its snapshots are at timesteps \[504, 1002\]\)"):
        evaluate.main(["--run", str(run_dir), "--load-checkpoint", "7"])


def test_a_run_folder_of_the_older_layout_still_reads(run_dir, tmp_path) -> None:
    """Runs written before the parameter folder had args.yml / config.yml at their root: evaluate, plot and resume
    find them there."""
    import shutil

    from sb3_eps.zoo.plotting import find_run_dirs, load_curve

    old = tmp_path / "gdq" / f"{ENV_ID}_1"
    shutil.copytree(run_dir, old)
    for name in ("args.yml", "config.yml"):
        (old / ENV_ID / name).rename(old / name)
    shutil.rmtree(old / ENV_ID)
    assert find_run_dirs([tmp_path]) == [old] and load_curve(old).algo == "gdq"
    assert evaluate.main(["--run", str(old), "-n", "2", "--n-envs", "1"]) == 0
    assert train.main(["--resume", str(old)]) == 0  # finished already: says so and exits 0


def test_rl_zoo_plot_scripts_read_the_log_folder(run_dir, tmp_path, monkeypatch) -> None:
    """RL Zoo's own all_plots (evaluations.npz of <folder>/<algo>/<env id>_<n>/) and plot_train (monitor.csv through
    SB3's load_results) read a log folder of ours."""
    import pickle

    pytest.importorskip("seaborn")  # all_plots imports it (rl_zoo3's plots extra); the dev extra installs it
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    from rl_zoo3.plots.all_plots import all_plots
    from rl_zoo3.plots.plot_train import plot_train

    folder, output = run_dir.parent.parent, tmp_path / "results"
    for key, ours in (("results", "results"), ("successes", "successes")):
        monkeypatch.setattr("sys.argv", ["all_plots", "-a", "gdq", "-e", ENV_ID, "-f", str(folder), "--no-display",
                                         "-o", str(output), "-k", key, "-max", "100000"])  # fmt: skip
        all_plots()
        with open(f"{output}.pkl", "rb") as file:
            (curve,) = pickle.load(file)[ENV_ID].values()
        evaluations = np.load(run_dir / "evaluations.npz")
        assert list(curve["timesteps"]) == list(evaluations["timesteps"])
        assert np.allclose(curve["mean"], evaluations[ours].mean(axis=1))  # one run: the mean over its episodes
        plt.close("all")
    monkeypatch.setattr("sys.argv", ["plot_train", "-a", "gdq", "-e", ENV_ID, "-f", str(folder), "-w", "2"])
    plot_train()
    (line,) = plt.gcf().axes[0].get_lines()
    monitor = read_monitor(run_dir / "monitor.csv")[1]
    assert len(line.get_ydata()) == len(monitor["r"]) - 1  # a rolling mean of 2 over the team returns
    plt.close("all")


def test_read_progress_gives_old_logs_the_sb3_keys(tmp_path) -> None:
    """progress.csv files written before the SB3 keys (the committed records) read with both names."""
    from research.results import read_progress

    path = tmp_path / "progress.csv"
    path.write_text("time/ticks,eval/team_return,eval/length,rollout/team_return\n10,1.5,25,\n20,,,2.0\n")
    log = read_progress(path)
    assert log["eval/mean_reward"][0] == 1.5 and log["eval/mean_ep_length"][0] == 25
    assert log["rollout/ep_rew_mean"][1] == 2.0 and np.isnan(log["eval/mean_reward"][1])


def test_evaluate_prints_and_saves_the_team_metrics(run_dir, tmp_path, capsys) -> None:
    output = tmp_path / "eval.json"
    assert evaluate.main(["--run", str(run_dir), "-n", "4", "--n-envs", "2", "--output", str(output)]) == 0
    printed = capsys.readouterr().out
    assert "success" in printed and "team return" in printed and "+/-" in printed
    summary = json.loads(output.read_text())
    assert summary["n_episodes"] == 4 and len(summary["episodes"]) == 4
    assert (summary["env_id"], summary["env_kwargs"], summary["level_set"]) == (ENV_ID, {}, None)  # its world
    for key in ("success_rate", "collision_rate", "team_return_mean", "team_return_std", "length_mean"):
        assert key in summary
    # RL Zoo's lookup by algo / env / folder, the best model, a GIF, another compatible world.
    folder = run_dir.parent.parent
    gif = tmp_path / "play.gif"
    argv = ["--algo", "gdq", "--env", ENV_ID, "-f", str(folder), "--load-best", "-n", "2", "--gif", str(gif)]
    assert evaluate.main(argv) == 0
    assert (run_dir / f"eval_{ENV_ID}_best.json").is_file()
    assert gif.stat().st_size > 0


def test_evaluate_refuses_a_world_of_another_kind(run_dir) -> None:
    with pytest.raises(ConfigError, match="observation_space"):
        evaluate.main(["--run", str(run_dir), "--eval-env", "MultiRobotNav-2-v0", "-n", "1"])


def test_plot_writes_curves_and_aggregates(run_dir, tmp_path, capsys) -> None:
    output = tmp_path / "curves.png"
    assert plot.main([str(run_dir.parent), "-o", str(output), "--window", "10", "--aggregate"]) == 0
    assert output.stat().st_size > 10_000
    assert output.with_suffix(".aggregate.csv").is_file()
    assert "IQM" in capsys.readouterr().out
    assert plot.main([str(run_dir), "-o", str(tmp_path / "evals.png"), "--eval"]) == 0
    assert (tmp_path / "evals.png").is_file()
    # A run beside committed greedy-evaluation records (docs/results), and the records alone.
    records = tmp_path / "records"
    records.mkdir()
    (records / f"gdq_{ENV_ID}_seed0.jsonl").write_text('{"ticks": 250, "success_rate": 0.5, "team_return_mean": 1}\n')
    assert plot.main([str(run_dir), "-o", str(tmp_path / "both.png"), "--records", str(records)]) == 0
    assert "2 runs" in capsys.readouterr().out
    assert plot.main(["-o", str(tmp_path / "records.png"), "--records", str(records)]) == 0


def test_benchmark_writes_a_table(run_dir, tmp_path) -> None:
    output = tmp_path / "benchmark.md"
    argv = ["-f", str(run_dir.parent.parent), "-n", "2", "--n-envs", "1", "-o", str(output)]
    assert benchmark.main(argv) == 0
    table = output.read_text()
    assert "| GDQ | CooperativeNavigation-v0 | CooperativeNavigation-v0 | 1 |" in table
    (result,) = json.loads(output.with_suffix(".json").read_text())
    assert (result["env_id"], result["env_kwargs"], result["n_episodes"]) == (ENV_ID, {}, 2)


def test_single_agent_pretraining_warm_starts_a_multi_agent_model(tmp_path) -> None:
    """Paper Table III: train on the single-agent world, then --init-from loads the agent network."""
    tiny = ["policy_kwargs:dict(net_arch=[16], stream_arch=[16], agent_target=True)", "learning_starts:100",
            "batch_size:16", "buffer_size:1000", "n_envs:1"]  # fmt: skip
    single = "CooperativeNavigationSingle-v0"
    argv = train_args(tmp_path / "pre", "--eval-freq", "0", "--hyperparams", *tiny, env_id=single, n=400)
    assert train.main(argv) == 0
    source = tmp_path / "pre" / "gdq" / f"{single}_1" / f"{single}.zip"
    # No gradient step (learning_starts beyond the budget): the multi-agent model keeps the loaded weights.
    warm = [*tiny[:1], "learning_starts:100000", "n_envs:1"]
    argv = train_args(tmp_path / "multi", "--eval-freq", "0", "--init-from", str(source), "--hyperparams", *warm, n=60)
    assert train.main(argv) == 0
    _, loaded, _ = load_from_zip_file(tmp_path / "multi" / "gdq" / f"{ENV_ID}_1" / f"{ENV_ID}.zip")
    _, original, _ = load_from_zip_file(source)
    for key, value in original["policy"].items():
        if key.startswith(("q_net.", "q_net_target.")):
            assert th.equal(loaded["policy"][key], value), key
    assert any(key.startswith("global_value_net.") for key in loaded["policy"])
    with pytest.raises(ConfigError, match="does not fit"):
        other = "policy_kwargs:dict(net_arch=[32], stream_arch=[16])"
        train.main(train_args(tmp_path / "bad", "--eval-freq", "0", "--init-from", str(source), "--hyperparams", other, n=60))
    assert not (tmp_path / "bad").exists()


def test_a_run_reports_its_last_evaluation_against_its_best(run_dir, tmp_path) -> None:
    from sb3_eps.zoo.callbacks import final_against_best

    report = (run_dir / "final_vs_best.txt").read_text()
    assert report.startswith("last evaluation: success") and "best: success" in report
    # A run that fell after its best evaluation says so and names best_model.zip and --load-best.
    records = {
        "timesteps": [10, 20, 30], "ticks": [5, 10, 15], "results": [[1.0, 1.0], [3.0, 2.0], [0.0, -1.0]],
        "successes": [[0.0, 1.0], [1.0, 1.0], [0.0, 0.0]],
    }  # fmt: skip
    line = final_against_best(records, tmp_path)
    assert "success 0%," in line and "best: success 100% at tick 10" in line
    assert "WARNING" in line and "--load-best" in line and "best_model.zip" in line
    records["successes"][-1] = [1.0, 1.0]
    assert "WARNING" not in final_against_best(records, tmp_path)
    assert final_against_best({"timesteps": []}, tmp_path) is None


def test_record_curves_read_the_committed_evaluation_records(tmp_path) -> None:
    from sb3_eps.zoo.plotting import plot_learning_curves, record_curves

    rows = [{"ticks": 10_000 * k, "success_rate": 0.1 * k, "team_return_mean": float(k)} for k in (1, 2, 3)]
    path = tmp_path / "eps_gdq_MultiRobotNav-4-v0_seed7.jsonl"
    path.write_text("\n".join(json.dumps(row) for row in rows) + "\n")
    (curve,) = record_curves([tmp_path])
    assert (curve.algo, curve.env_id) == ("eps_gdq", "MultiRobotNav-4-v0")
    assert list(curve.x) == [10_000, 20_000, 30_000] and np.allclose(curve.values["success"], [0.1, 0.2, 0.3])
    bad = tmp_path / "bad" / "gdq_MultiRobotNav-4-v0_seed0.jsonl"
    bad.parent.mkdir()
    bad.write_text('{"ticks": 1}\n')
    with pytest.raises(ConfigError, match="not an evaluation record"):
        record_curves([bad])
    with pytest.raises(ConfigError, match="does not exist"):
        record_curves([tmp_path / "missing"])
    output = plot_learning_curves([curve], tmp_path / "refs.png", window=1)
    assert output.stat().st_size > 10_000


def test_a_run_on_stacked_scans_is_evaluated_on_worlds_that_stack_them(tmp_path) -> None:
    """A run trained with ``--env-kwargs lidar_frames:2`` evaluates (on its world and on the unseen room) with its own
    world arguments; overriding them with a one-scan world is refused in one line."""
    argv = train_args(tmp_path, "--hyperparams", *TINY, "--env-kwargs", "lidar_frames:2", "max_episode_steps:30",
                      env_id="MultiRobotNav-2-v0", n=400)  # fmt: skip
    assert train.main(argv) == 0
    (run,) = (tmp_path / "gdq").iterdir()
    output = tmp_path / "eval.json"
    assert evaluate.main(["--run", str(run), "-n", "2", "--n-envs", "1", "--output", str(output)]) == 0
    assert json.loads(output.read_text())["n_episodes"] == 2
    room = ["--run", str(run), "--eval-env", "MultiRobotNavUnseen-4-v0", "-n", "1", "--n-envs", "1"]
    assert evaluate.main([*room, "--output", str(tmp_path / "room.json"), "--env-kwargs", "max_episode_steps:20"]) == 0
    # The JSON names the world: the run's own options updated by --env-kwargs.
    room_summary = json.loads((tmp_path / "room.json").read_text())
    assert room_summary["env_id"] == "MultiRobotNavUnseen-4-v0" and room_summary["n_episodes"] == 1
    assert room_summary["env_kwargs"] == {"lidar_frames": 2, "max_episode_steps": 20}
    with pytest.raises(ConfigError, match=r"observation_space .*58"):
        evaluate.main(["--run", str(run), "-n", "1", "--env-kwargs", "lidar_frames:1"])


def test_learning_curves_put_team_sizes_in_numeric_order() -> None:
    """Fig. 4's panels read 2, 4, 8, 12 robots, as the paper's, not 12, 2, 4, 8 as text sorts them."""
    from sb3_eps.zoo.plotting import RunCurve, draw_learning_curves

    curves = [RunCurve(pathlib.Path(f"r{n}"), "gdq", f"MultiRobotNav-{n}-v0", np.arange(3.0), {"r": np.ones(3)})
              for n in (12, 2, 8, 4)]  # fmt: skip
    figure = draw_learning_curves(curves, window=1)
    titles = [axis.get_title() for axis in figure.axes]
    assert titles == [f"MultiRobotNav-{n}-v0" for n in (2, 4, 8, 12)]
