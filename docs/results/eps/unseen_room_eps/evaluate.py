"""The final models of this screen (``rules.md``) on the varied unseen room: greedy, 100 episodes, evaluation seed
20000, one JSON line per model (a rerun skips lines already there); the 8-robot screen's evaluation, one room.

    python docs/results/eps/unseen_room_eps/evaluate.py MODEL.zip ... --out docs/results/eps/unseen_room_eps/unseen_room.jsonl

A model file is named ``<arm>_seed<k>.zip`` (``benchmarks/team_size_ladder.py --save-models``).
"""

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "many_robots" / "eight_robot_screen"))
from evaluate_unseen import main

if __name__ == "__main__":
    main(rooms=("MultiRobotNavUnseen-4-varied-v0",))
