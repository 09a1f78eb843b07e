"""The final models of this folder's rule on the fixed room, the varied room and the open 4-robot arena: greedy,
100 episodes each, evaluation seed 20000, one JSON line per model and world (a rerun skips lines already there).

    python docs/results/many_robots/unseen_room_crowd_alternation/evaluate.py MODEL.zip ... \\
        --out docs/results/many_robots/unseen_room_crowd_alternation/final_models.jsonl
"""

import importlib.util
import pathlib

HERE = pathlib.Path(__file__).resolve().parent
spec = importlib.util.spec_from_file_location("evaluate_unseen", HERE.parent / "eight_robot_screen" / "evaluate_unseen.py")
evaluate_unseen = importlib.util.module_from_spec(spec)
spec.loader.exec_module(evaluate_unseen)

if __name__ == "__main__":
    evaluate_unseen.main(rooms=(*evaluate_unseen.ROOMS, "MultiRobotNav-4-v0"))
