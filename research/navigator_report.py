"""The navigator's report table (rule N7 of ``docs/results/navigator/rules.md``) from its evaluation records.

Reads ``docs/results/navigator/report/navigator_seed<k>_on_<env id>.json`` (one per seed and world, written by
``python -m sb3_eps.evaluate --output``), checks that each record names the world it was played in, and prints the
markdown table of the page: per world the target, the mean success over the seeds, each seed's success, the lowest
seed's distance to the mean, the mean collisions, and whether the target is met::

    python research/navigator_report.py [--records docs/results/navigator/report] [--against OTHER_RECORDS]

``--against`` adds a column: the mean over seeds of this table's success minus the other records' (the same seeds and
evaluation problems, so each difference is paired by seed).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re

# world -> (what the page calls it, the target success, level set the record must name)
WORLDS: dict[str, tuple[str, float | None, str | None]] = {
    "MultiRobotNavRooms-4-test-v0": ("test rooms, 4 robots", 0.95, "test"),
    "MultiRobotNavRooms-8-test-v0": ("test rooms, 8 robots", 0.90, "test"),
    "MultiRobotNavRooms-12-test-v0": ("test rooms, 12 robots", 0.85, "test"),
    "MultiRobotNav-4-v0": ("open arena, 4 robots", 0.95, None),
    "MultiRobotNav-8-v0": ("open arena, 8 robots", 0.95, None),
    "MultiRobotNav-12-v0": ("open arena, 12 robots", 0.95, None),
    "MultiRobotNavUnseen-4-varied-v0": ("varied unseen room (a validation room)", 0.95, None),
    "MultiRobotNav-24-v0": ("24-robot arena", 0.85, None),
    "MultiRobotNavRooms-8-validation-v0": ("validation rooms, 8 robots (for the ablations)", None, "validation"),
}
ROOM_COLLISION_BAR = 0.03  # the collisions bar in test rooms
SPREAD_BAR = 0.10  # no seed more than 10 points below its mean


def load(records: pathlib.Path) -> dict[str, dict[int, dict]]:
    """:return: world -> seed -> record, checked against the world it says it was played in"""
    table: dict[str, dict[int, dict]] = {}
    for path in sorted(records.glob("navigator_seed*_on_*.json")):
        match = re.fullmatch(r"navigator_seed(\d+)_on_(.+)\.json", path.name)
        if match is None:
            continue
        seed, env_id = int(match.group(1)), match.group(2)
        record = json.loads(path.read_text())
        if record["env_id"] != env_id or record["n_episodes"] != 100:
            raise ValueError(f"{path.name}: the record says {record['env_id']!r}, {record['n_episodes']} episodes")
        expected_set = WORLDS.get(env_id, ("", None, None))[2]
        if record.get("level_set") != expected_set:
            raise ValueError(f"{path.name}: level set {record.get('level_set')!r}, expected {expected_set!r}")
        table.setdefault(env_id, {})[seed] = record
    return table


def render(table: dict[str, dict[int, dict]], against: dict[str, dict[int, dict]] | None = None) -> str:
    lines = [
        "| world | target | mean success (seeds 0-4) | per seed | lowest seed below mean | mean collisions | met |"
        + (" against the other records (paired) |" if against is not None else ""),
        "|---|---|---|---|---|---|---|" + ("---|" if against is not None else ""),
    ]
    for env_id, (name, target, _) in WORLDS.items():
        runs = table.get(env_id, {})
        if not runs:
            lines.append(f"| {name} | {'' if target is None else f'>= {target:.0%}'} | not played | | | | |")
            continue
        seeds = sorted(runs)
        success = [runs[s]["success_rate"] for s in seeds]
        collisions = [runs[s]["collision_rate"] for s in seeds]
        mean, mean_collisions = sum(success) / len(success), sum(collisions) / len(collisions)
        below = mean - min(success)
        met = ""
        if target is not None:
            ok = mean >= target and below <= SPREAD_BAR and len(seeds) == 5
            if env_id.startswith("MultiRobotNavRooms") and mean_collisions > ROOM_COLLISION_BAR:
                ok = False
            met = "yes" if ok else "no"
        per_seed = " / ".join(f"{100 * x:.0f}" for x in success)
        line = (
            f"| {name} | {'' if target is None else f'>= {100 * target:.0f} %'} | {100 * mean:.1f} % | {per_seed} "
            f"(seeds {', '.join(map(str, seeds))}) | {100 * below:.0f} | {100 * mean_collisions:.1f} % | {met} |"
        )
        if against is not None:
            other = against.get(env_id, {})
            pairs = [runs[s]["success_rate"] - other[s]["success_rate"] for s in seeds if s in other]
            line += f" {100 * sum(pairs) / len(pairs):+.1f} points ({len(pairs)} seeds) |" if pairs else " not played |"
        lines.append(line)
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=pathlib.Path, default=pathlib.Path("docs/results/navigator/report"))
    parser.add_argument("--against", type=pathlib.Path, default=None, help="records to pair with, seed by seed")
    args = parser.parse_args()
    print(render(load(args.records), None if args.against is None else load(args.against)))


if __name__ == "__main__":
    main()
