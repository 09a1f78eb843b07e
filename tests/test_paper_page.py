"""research/paper_page.py: the quick pipeline runs and renders a page; the committed page is what its records render."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # research/ sits beside the package

from research import paper_page  # noqa: E402


def test_the_committed_page_and_status_are_what_the_records_render() -> None:
    changed = paper_page.render(paper_page.RUNS, paper_page.PAGE, ROOT / "README.md", check=True)
    assert changed == [], f"re-render with `python research/paper_page.py render`: {changed}"
    assert (paper_page.RESULTS / "paper" / paper_page.FIGURE_NAME).is_file()
    assert len((ROOT / "README.md").read_text().splitlines()) <= 130


def _copy_pages(tmp_path: Path) -> tuple[Path, Path]:
    page = tmp_path / "docs" / "results" / "README.md"
    (page.parent / "paper").mkdir(parents=True)
    shutil.copy(paper_page.PAGE, page)
    shutil.copy(paper_page.RESULTS / "paper" / paper_page.FIGURE_NAME, page.parent / "paper")
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    return page, tmp_path / "README.md"


def test_a_hand_edit_of_the_page_or_the_status_fails_the_check(tmp_path: Path) -> None:
    page, readme = _copy_pages(tmp_path)
    assert paper_page.render(paper_page.RUNS, page, readme, check=True) == []
    page.write_text(page.read_text().replace("92.4 +/- 3.7 %", "95.0 +/- 3.7 %"))
    status = readme.read_text()
    assert " not reproduced" in status  # the status table has a verdict to edit
    readme.write_text(status.replace(" not reproduced", " reproduced", 1))
    assert paper_page.render(paper_page.RUNS, page, readme, check=True) == [str(page), str(readme)]


def test_a_bad_argument_is_one_line_and_status_2(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text("# no status markers\n")
    command = [sys.executable, str(ROOT / "research" / "paper_page.py"), "render", "--readme", str(readme)]
    result = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"python research/paper_page.py: error: {readme}: no status markers "
        f"({paper_page.README_BEGIN} ... {paper_page.README_END})"
    ]
    assert readme.read_text() == "# no status markers\n"


def test_success_verdicts_at_the_tolerance() -> None:
    assert paper_page.success_verdict(None, 0.9) == paper_page.NOT_RUN
    assert paper_page.success_verdict(0.85, 0.9) == "reproduced"
    assert paper_page.success_verdict(0.84, 0.9) == "not reproduced"
    assert paper_page.success_verdict(0.96, 0.9) == "better here"


def _cell(successes: list[float], every: int = 50_000, training: dict[str, float] | None = None) -> paper_page.Cell:
    ticks = np.arange(1, len(successes) + 1) * every
    values = np.array(successes)
    seed = paper_page.Seed("synthetic", ticks, values, values * 10, 1 - values, training=training or {})
    return paper_page.Cell([seed], "synthetic")


def _findings(**cells: paper_page.Cell) -> paper_page.Findings:
    fig4 = {(n, algo): cells.get(f"{algo}{n}") for n in paper_page.FIG4_WORLDS for algo in paper_page.FIG4_ALGOS}
    table1 = {algo: cells.get(f"{algo}_mpe") for algo in paper_page.TABLE1_ALGOS}
    return paper_page.Findings(table1, fig4, {}, {}, [])


def test_fig4_verdicts_read_the_paper_point_or_say_the_runs_end_before_it() -> None:
    findings = _findings(
        gdq4=_cell([0.5, 0.8, 0.9]),  # the paper: 88 % at 175k; ours end at 150k, already there
        qmix4=_cell([0.3, 0.6, 0.7]),  # the paper: 90 % at 110k; ours 60 % at 100k
        eps_gdq4=_cell([0.5, 0.6]),  # the paper: 90 % at 100k; ours 60 % at 100k
        iql4=_cell([0.2, 0.3, 0.4]),
        qmix8=_cell([0.1, 0.15]),
        gdq8=_cell([0.5, 0.8]),
        eps_gdq8=_cell([0.5, 0.7]),
    )
    assert paper_page.fig4_verdict(findings, 4, "gdq") == ("90.0 % at 150k", "reproduced")
    assert paper_page.fig4_verdict(findings, 4, "qmix") == ("60.0 % at 110k", "not reproduced")
    assert paper_page.fig4_verdict(findings, 4, "eps_gdq") == ("60.0 % at 100k", "not reproduced")
    assert paper_page.fig4_verdict(findings, 8, "qmix")[1] == "reproduced"  # "does not learn": below 20 %
    assert paper_page.fig4_verdict(findings, 8, "eps_gdq")[1] == "not reproduced"  # behind GDQ
    assert paper_page.fig4_verdict(findings, 4, "iql")[1] == "reproduced"  # "lowest of the four"
    assert paper_page.fig4_verdict(findings, 8, "gdq")[1] == paper_page.NOT_RUN  # above IL and QMIX: no IL here
    findings.fig4[(8, "iql")] = _cell([0.3, 0.85])
    assert paper_page.fig4_verdict(findings, 8, "gdq")[1] == "not reproduced"  # IL ends above GDQ's 80 %
    findings.fig4[(8, "iql")] = _cell([0.3, 0.4])
    assert paper_page.fig4_verdict(findings, 8, "gdq")[1] == "reproduced"
    assert paper_page.fig4_verdict(findings, 12, "gdq") == ("-", paper_page.NOT_RUN)
    short = _findings(qmix4=_cell([0.3, 0.6], every=25_000))  # ends at 50k, below the paper's 90 %
    assert paper_page.fig4_verdict(short, 4, "qmix") == ("60.0 % at 50k (runs end there)", paper_page.NOT_RUN)


def test_table1_verdicts_follow_the_papers_ordering() -> None:
    findings = _findings(
        iql_mpe=_cell([0.5], training={"r": -80.0, "collision": 0.30}),
        eps_iql_mpe=_cell([0.5], training={"r": -75.0, "collision": 0.25}),
        gdq_mpe=_cell([0.5], training={"r": -70.0, "collision": 0.31}),  # more collisions than IL
    )
    verdicts = {algo: paper_page.table1_verdict(findings, algo) for algo in paper_page.TABLE1_ALGOS}
    assert verdicts == {
        "iql": "reference",
        "eps_iql": "reproduced",
        "gdq": "not reproduced",
        "eps_gdq": paper_page.NOT_RUN,
    }


def test_the_stage_snapshot_is_the_first_to_reach_its_success(tmp_path: Path) -> None:
    timesteps = np.array([100, 200, 300, 400])
    successes = np.array([[0.0, 0.0], [0.5, 1.0], [1.0, 1.0], [1.0, 1.0]])
    np.savez(tmp_path / "evaluations.npz", timesteps=timesteps, ticks=timesteps, eps_ticks=timesteps * 0,
             successes=successes, results=successes * 10)  # fmt: skip
    for steps in (100, 200, 400):  # no snapshot at 300
        (tmp_path / f"rl_model_{steps}_steps.zip").touch()
    assert paper_page.pick_snapshot(tmp_path, 0.5)["ticks"] == 200
    picked = paper_page.pick_snapshot(tmp_path, 0.95)
    assert picked["ticks"] == 400 and picked["path"].endswith("rl_model_400_steps.zip")
    assert paper_page.pick_snapshot(tmp_path, 1.01) is None


@pytest.mark.timeout(600)  # 150-280 s measured on 2 cores shared at load 9-10 (about 90 s of CPU)
def test_the_quick_pipeline_runs_every_item_and_renders_its_page(tmp_path: Path) -> None:
    page = tmp_path / "page" / "README.md"
    status = paper_page.main(["run", "--quick", "-f", str(tmp_path / "runs"), "--page", str(page), "--readme", ""])
    assert status == 0
    text = page.read_text()
    table1 = text.split("## Table I")[1].split("## Fig. 4")[0]
    assert table1.count("(1 run of this command)") == 4 and "not run yet" not in table1
    finals = list((tmp_path / "runs" / "table1").glob(f"*/*/{paper_page.FINAL_EVAL_NAME}"))
    assert len(finals) == 4  # each Table I model's final evaluation, on the page's greedy-return column
    fig4 = text.split("## Fig. 4")[1].split("## Table II")[0]
    assert fig4.count("`fig4_n4/") == 4
    table2 = text.split("## Table II")[1].split("## Table III")[0]
    assert "fig4_n4/qmix/*/eval_MultiRobotNavUnseen-4-v0.json" in table2
    table3 = text.split("## Table III")[1].split("## The package")[0]
    assert "| 50 % |" in table3 and "`stage50/gdq/` (1 run of this command)" in table3
    assert (page.parent / "paper" / paper_page.FIGURE_NAME).is_file()


def test_a_runs_seconds_add_the_stretches_of_a_resumed_run() -> None:
    # A clock started again: the stretch before it ends at its last t.
    assert paper_page.monitor_seconds(np.array([5.0, 60.0, 120.0, 3.0, 40.0, np.nan])) == 160.0
    # A stop counted in t (checkpoints written before the clock left stops out): it counts as the median gap.
    assert paper_page.monitor_seconds(np.array([5.0, 10.0, 20.0, 2020.0, 2030.0])) == 5.0 + 5.0 + 10.0 + 10.0 + 10.0
    assert paper_page.monitor_seconds(np.array([1.0, 2.0])) == 2.0
    assert np.isnan(paper_page.monitor_seconds(np.array([])))


def test_the_full_commands_time_counts_every_planned_run_once() -> None:
    findings = paper_page.collect(paper_page.RUNS)
    time = paper_page.command_time(findings)
    planned = sum(paper_page._grid_runs(name)[0] for name in ["table1", "pretrain", *(f"fig4_n{n}" for n in (2, 4, 8, 12))])
    planned += len(paper_page.PRETRAIN_STAGES) * paper_page._grid_runs("fig4_n4")[0] // len(paper_page.FIG4_ALGOS)
    unmeasured = sum(int(item.split("(")[1].split()[0]) for item in time.unmeasured)
    assert time.n_measured + time.n_estimated + unmeasured == planned
    assert time.measured_s > 0 and "Every record:" in paper_page.full_command_line(findings)


def test_a_pre_training_stage_never_reached_is_said_so_not_left_unrun() -> None:
    findings = _findings(eps_gdq4=_cell([0.5, 0.6, 0.8]))
    start = paper_page.one_point("snapshot", 0.61, 1.0, np.nan, 50_000)
    findings.table3 = {0.5: (start, _cell([0.5, 0.7])), 0.75: (None, None), 0.95: (None, None)}
    assert paper_page.table3_verdicts(findings) == {0.5: "not reproduced", 0.75: "not run yet", 0.95: "not run yet"}
    findings.pretrain = _cell([0.3, 0.8, 0.91, 0.9]).seeds  # finished: 91 % at best
    verdicts = paper_page.table3_verdicts(findings)
    assert verdicts[0.95] == paper_page.STAGE_NOT_REACHED and verdicts[0.75] == "not run yet"
    section = "\n".join(paper_page.section_table3(findings))
    assert "never reached in 200k (best 91.0 % at 150k)" in section and "Not run yet" in section


def _finished_run(run_dir: Path, algo: str = "eps_iql", seed: int = 3) -> dict[str, float]:
    """A finished run folder of sb3_eps.train's layout, written by hand; returns its training means."""
    env = paper_page.MPE
    (run_dir / env).mkdir(parents=True)
    (run_dir / env / "args.yml").write_text(f"algo: {algo}\nenv: {env}\nseed: {seed}\n")
    (run_dir / env / "config.yml").write_text("gamma: 0.95\n")
    rng = np.random.default_rng(0)
    n = 300  # episodes ending over 120k ticks: three bins of 50k, the last one partial
    ticks = np.sort(rng.integers(1, 120_000, n))
    r = rng.normal(-40, 5, n)
    collision, spawn_out = rng.integers(0, 2, n), rng.integers(0, 2, n)
    rows = [f"{r[i]},25,{ticks[i] / 100},{ticks[i]},0,0,{collision[i]},{spawn_out[i]}" for i in range(n)]
    header = '#{"t_start": 1.0, "env_id": "' + env + '", "algo": "' + algo + '", "n_agents": 3}'
    (run_dir / "monitor.csv").write_text(
        "\n".join([header, "r,l,t,ticks,eps_ticks,world,collision,collision_after_spawn", *rows]) + "\n"
    )
    np.savez(run_dir / "evaluations.npz", timesteps=np.array([360_000]), ticks=np.array([120_000]),
             eps_ticks=np.array([0]), successes=np.array([[0.0, 1.0]]), results=np.array([[-30.0, -20.0]]),
             collisions=np.array([[0.0, 0.0]]))  # fmt: skip
    (run_dir / "final_vs_best.txt").write_text("last evaluation")
    rounds = [{"round": k, "accepted": k in (2, 5)} for k in range(1, 8)]
    (run_dir / "eps_rounds.jsonl").write_text(
        "".join(f'{{"round": {x["round"]}, "accepted": {str(x["accepted"]).lower()}}}\n' for x in rounds)
    )
    final = {"success_rate": 0.12, "team_return_mean": -28.5, "collision_rate": 0.3, "occupied_landmarks_mean": 1.4}
    (run_dir / paper_page.FINAL_EVAL_NAME).write_text(__import__("json").dumps(final))
    return {"r": float(r.mean()), "collision": float(collision.mean()), "collision_after_spawn": float(spawn_out.mean())}


def test_an_adopted_run_reads_as_its_monitor_did(tmp_path: Path) -> None:
    means = _finished_run(tmp_path / "elsewhere" / "eps_iql_s3")
    before = paper_page.read_run_seed(tmp_path / "elsewhere" / "eps_iql_s3")
    [target] = paper_page.adopt("table1", [tmp_path / "elsewhere" / "eps_iql_s3"], tmp_path / "runs")
    assert target == tmp_path / "runs" / "table1" / "eps_iql" / f"{paper_page.MPE}_seed3"
    assert not (target / "monitor.csv").exists() and (target / paper_page.TRAINING_CURVE_NAME).is_file()
    assert (target / paper_page.MPE / "config.yml").is_file()
    seed = paper_page.read_run_seed(target)
    for key, value in means.items():  # the binned curve keeps the episode-weighted means (4 decimals a bin)
        assert seed.training[key] == pytest.approx(value, abs=1e-4) and before.training[key] == pytest.approx(value)
    assert seed.wall_s == pytest.approx(before.wall_s, abs=1e-3)
    assert seed.eps_rounds == (7, 2)
    cell = paper_page.run_cell(tmp_path / "runs" / "table1", "eps_iql", paper_page.MPE)
    assert cell is not None and list(cell.final("success")) == [0.12]  # the final evaluation, not the last point
    assert "2/7" in "\n".join(
        paper_page.section_table1(
            paper_page.Findings({"eps_iql": cell, "iql": None, "gdq": None, "eps_gdq": None}, {}, {}, {}, [])
        )
    )
    with pytest.raises(paper_page.ConfigError, match="exists"):
        paper_page.adopt("table1", [tmp_path / "elsewhere" / "eps_iql_s3"], tmp_path / "runs")
    (tmp_path / "elsewhere" / "eps_iql_s3" / "final_vs_best.txt").unlink()
    with pytest.raises(paper_page.ConfigError, match="not finished"):
        paper_page.adopt("table1", [tmp_path / "elsewhere" / "eps_iql_s3"], tmp_path / "other")


def test_table1_collisions_leave_spawn_overlaps_out_where_both_rows_record_them() -> None:
    # All collisions: EPS-IL has more; spawn overlaps left out: fewer. The verdict reads the second.
    findings = _findings(
        iql_mpe=_cell([0.5], training={"r": -80.0, "collision": 0.30, "collision_after_spawn": 0.20}),
        eps_iql_mpe=_cell([0.5], training={"r": -75.0, "collision": 0.32, "collision_after_spawn": 0.15}),
    )
    assert paper_page.table1_verdict(findings, "eps_iql") == "reproduced"
    findings.table1["iql"].seeds[0].training.pop("collision_after_spawn")  # type: ignore[union-attr]
    assert paper_page.table1_verdict(findings, "eps_iql") == "not reproduced"


def test_table1_verdicts_pair_the_seeds_both_rows_have() -> None:
    def seed(name: str, r: float, collision: float) -> paper_page.Seed:
        one = np.array([0.0])
        return paper_page.Seed(name, one, one, one, one, training={"r": r, "collision": collision})

    # IL's seed 1 is weak; GDQ has only seed 0, where IL is better: no ordering on the seed both have.
    il = paper_page.Cell([seed("s0", -30.0, 0.2), seed("s1", -60.0, 0.5)], "synthetic")
    gdq = paper_page.Cell([seed("s0", -31.0, 0.1)], "synthetic")
    findings = _findings()
    findings.table1.update(iql=il, gdq=gdq)
    assert paper_page.table1_verdict(findings, "gdq") == "not reproduced (1 paired seed so far)"
    gdq.seeds.append(seed("s1", -40.0, 0.3))
    # Paired gains: reward -1 and +20 (mean 9.5, SE 10.5), collisions 0.1 and 0.2 (mean 0.15, SE 0.05).
    assert paper_page.table1_verdict(findings, "gdq") == "within noise in reward"


def test_table1_orderings_count_only_beyond_twice_the_paired_standard_error() -> None:
    def seed(name: str, r: float, collision: float) -> paper_page.Seed:
        one = np.array([0.0])
        return paper_page.Seed(name, one, one, one, one, training={"r": r, "collision": collision})

    def verdict(il: list[tuple[float, float]], eps: list[tuple[float, float]]) -> str:
        findings = _findings()
        findings.table1.update(
            iql=paper_page.Cell([seed(f"s{k}", *values) for k, values in enumerate(il)], "synthetic"),
            eps_iql=paper_page.Cell([seed(f"s{k}", *values) for k, values in enumerate(eps)], "synthetic"),
        )
        return paper_page.table1_verdict(findings, "eps_iql")

    il = [(-35.0, 0.25), (-34.0, 0.24), (-36.0, 0.27), (-35.5, 0.26)]
    # Reward +1.0, +1.2, +0.8, +1.1 and collisions 2-3 points fewer on every seed: both beyond 2 SE.
    clear = [(-34.0, 0.22), (-32.8, 0.22), (-35.2, 0.24), (-34.4, 0.23)]
    assert verdict(il, clear) == "reproduced"
    # The means still order as the paper's (reward +0.05, collisions -0.25 points) but the seeds disagree.
    mixed = [(-34.6, 0.26), (-34.3, 0.23), (-35.8, 0.26), (-35.6, 0.26)]
    assert verdict(il, mixed) == "within noise in reward and collisions"
    # Worse on every seed: against the paper beyond the noise.
    worse = [(-37.0, 0.30), (-36.1, 0.28), (-38.2, 0.31), (-37.3, 0.30)]
    assert verdict(il, worse) == "not reproduced"


def test_the_best_per_world_ignores_cells_with_fewer_seeds() -> None:
    def cell(successes: list[float]) -> paper_page.Cell:
        one = np.array([1.0])
        return paper_page.Cell(
            [paper_page.Seed(f"s{k}", one, one * value, one, one * 0) for k, value in enumerate(successes)], "synthetic"
        )

    findings = _findings()
    findings.table1.update(gdq=cell([0.30, 0.32, 0.31]), eps_gdq=cell([0.40]))
    assert [label for env, label, _ in paper_page.best_rows(findings) if env == paper_page.MPE] == ["GDQ"]
    findings.table1["eps_gdq"] = cell([0.40, 0.30, 0.35])
    assert [label for env, label, _ in paper_page.best_rows(findings) if env == paper_page.MPE] == ["EPS-GDQ"]
