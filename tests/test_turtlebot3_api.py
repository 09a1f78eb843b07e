"""API compliance of the TurtleBot3 worlds: PettingZoo kit, SB3 check_env, determinism, bad input, pickling."""

from __future__ import annotations

import pickle
import types
import warnings
from typing import Any

import numpy as np
import pytest
from pettingzoo.test import max_cycles_test, parallel_api_test, render_test, state_test
from pettingzoo.utils import parallel_to_aec
from stable_baselines3.common.env_checker import check_env

from envs.turtlebot3 import MultiRobotNavEnv, SingleRobotNavEnv, save_gif
from envs.turtlebot3.world import display_available

# The registry's multi-robot ids and the constructor arguments they stand for (envs/__init__.py).
MULTI_ROBOT_IDS: dict[str, dict[str, Any]] = {
    "MultiRobotNav-2-v0": {"n_robots": 2},
    "MultiRobotNav-4-v0": {"n_robots": 4},
    "MultiRobotNav-8-v0": {"n_robots": 8},
    "MultiRobotNav-12-v0": {"n_robots": 12},
    "MultiRobotNavUnseen-4-v0": {"n_robots": 4, "scenario": "unseen"},
    "MultiRobotNavUnseen-4-varied-v0": {"n_robots": 4, "scenario": "unseen", "placement_jitter": 0.3},
    "MultiRobotNavBlocks-12-v0": {"n_robots": 12, "scenario": "blocks"},
}


@pytest.fixture(params=list(MULTI_ROBOT_IDS))
def env_kwargs(request: pytest.FixtureRequest) -> dict[str, Any]:
    return MULTI_ROBOT_IDS[request.param]


def test_parallel_api(env_kwargs: dict[str, Any]) -> None:
    env = MultiRobotNavEnv(**env_kwargs)
    with warnings.catch_warnings():
        # The kit's warnings are advisory; its assertions are the test.
        warnings.simplefilter("ignore")
        parallel_api_test(env, num_cycles=200)
    env.close()


def test_state(env_kwargs: dict[str, Any]) -> None:
    parallel_env = MultiRobotNavEnv(**env_kwargs)
    aec_env = parallel_to_aec(MultiRobotNavEnv(**env_kwargs))
    state_test(aec_env, parallel_env, num_cycles=20)
    assert parallel_env.state().shape == parallel_env.state_space.shape == (9 * env_kwargs["n_robots"],)
    aec_env.close()
    parallel_env.close()


def test_render(env_kwargs: dict[str, Any]) -> None:
    def env_fn(render_mode: str | None = None) -> Any:
        # The kit drives an AEC env; ours is parallel, so it goes through PettingZoo's converter.
        if render_mode == "human" and not display_available():
            # Headless: the kit may only exercise rgb_array (test_human_mode_without_display covers "human").
            env = parallel_to_aec(MultiRobotNavEnv(**env_kwargs, render_mode="rgb_array"))
            env.metadata["render_modes"] = ["rgb_array"]
            return env
        return parallel_to_aec(MultiRobotNavEnv(**env_kwargs, render_mode=render_mode, render_lidar=True))

    render_test(env_fn)


def test_max_cycles(env_kwargs: dict[str, Any]) -> None:
    # The kit wants a module with parallel_env(max_cycles=...) and env(max_cycles=...): our time limit.
    module = types.SimpleNamespace(
        parallel_env=lambda max_cycles: MultiRobotNavEnv(**env_kwargs, max_episode_steps=max_cycles),
        env=lambda max_cycles: parallel_to_aec(MultiRobotNavEnv(**env_kwargs, max_episode_steps=max_cycles)),
    )
    max_cycles_test(module)


def test_spaces_are_cached_and_shared() -> None:
    env = MultiRobotNavEnv(n_robots=3)
    before = env.observation_space("robot_0"), env.action_space("robot_0")
    env.reset(seed=1)
    for agent in env.possible_agents:
        assert env.observation_space(agent) is before[0]
        assert env.action_space(agent) is before[1]
    assert before[0].shape == (30,) and before[0].dtype == np.float32
    assert before[1].n == 20
    env.close()


def test_single_robot_check_env() -> None:
    env = SingleRobotNavEnv()
    check_env(env, warn=True, skip_render_check=True)
    env.close()
    check_env(SingleRobotNavEnv(render_mode="rgb_array"), skip_render_check=False)


def test_single_robot_episode_and_info() -> None:
    env = SingleRobotNavEnv(max_episode_steps=30)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert info["is_success"] is False and "team" in info
    for _ in range(30):
        obs, reward, terminated, truncated, info = env.step(2)  # stand still: -0.005 per tick, no ending
        assert reward == pytest.approx(-0.005)
        if terminated or truncated:
            break
    assert truncated and not terminated and info["team"]["ticks"] == 30
    with pytest.raises(RuntimeError, match="reset"):
        env.step(2)
    env.close()


def run_seeded(seed: int, n_steps: int = 200, **kwargs: Any) -> list[Any]:
    """Observations, rewards, ends and infos of ``n_steps`` random ticks, resetting at episode ends."""
    env = MultiRobotNavEnv(n_robots=4, max_episode_steps=60, **kwargs)
    record: list[Any] = []
    obs, infos = env.reset(seed=seed)
    record.append((obs, infos))
    action_rng = np.random.default_rng(seed)
    for _ in range(n_steps):
        actions = {agent: int(action_rng.integers(20)) for agent in env.agents}
        record.append(env.step(actions))
        if not env.agents:
            record.append(env.reset())
    env.close()
    return record


def flatten(record: list[Any]) -> list[Any]:
    """Turn nested dicts/tuples/arrays into comparable lists."""
    if isinstance(record, dict):
        return [(key, flatten(value)) for key, value in record.items()]
    if isinstance(record, (list, tuple)):
        return [flatten(value) for value in record]
    if isinstance(record, np.ndarray):
        return record.tolist()
    return record


@pytest.mark.parametrize("lidar_noise_std", [0.0, 0.02])
def test_seed_determinism_over_many_steps(lidar_noise_std: float) -> None:
    first = flatten(run_seeded(3, lidar_noise_std=lidar_noise_std))
    assert first == flatten(run_seeded(3, lidar_noise_std=lidar_noise_std))
    assert first != flatten(run_seeded(4, lidar_noise_std=lidar_noise_std))


def test_lidar_noise_changes_ranges_only() -> None:
    exact, noisy = MultiRobotNavEnv(2), MultiRobotNavEnv(2, lidar_noise_std=0.05)
    obs_exact, _ = exact.reset(seed=5)
    obs_noisy, _ = noisy.reset(seed=5)
    assert not np.allclose(obs_exact["robot_0"][:28], obs_noisy["robot_0"][:28])
    np.testing.assert_array_equal(obs_exact["robot_0"][28:], obs_noisy["robot_0"][28:])
    assert noisy.observation_space("robot_0").contains(obs_noisy["robot_0"])


def test_pickle_round_trip_continues_identically() -> None:
    env = MultiRobotNavEnv(n_robots=4)
    env.reset(seed=2)
    env.step(dict.fromkeys(env.agents, 17))
    copy = pickle.loads(pickle.dumps(env))
    actions = dict.fromkeys(env.agents, 13)
    assert flatten(env.step(actions)) == flatten(copy.step(actions))
    np.testing.assert_array_equal(env.state(), copy.state())
    env.close()
    copy.close()


def test_close_is_idempotent() -> None:
    env = SingleRobotNavEnv()
    env.reset(seed=0)
    env.close()
    env.close()


# --- bad input -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [1.5, "3", -1, True, [1]])
def test_bad_seed_raises(seed: Any) -> None:
    env = MultiRobotNavEnv(2)
    with pytest.raises(ValueError, match="seed"):
        env.reset(seed=seed)
    single = SingleRobotNavEnv()
    with pytest.raises(ValueError, match="seed"):
        single.reset(seed=seed)
    env.close()
    single.close()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_robots": 0}, "allowed 1 to 24"),
        ({"n_robots": 25}, "allowed 1 to 24"),
        ({"n_robots": 5, "scenario": "unseen"}, "allowed 1 to 4"),
        ({"n_robots": 2.0}, "n_robots must be an int"),
        ({"scenario": "maze"}, "Unknown scenario"),
        ({"max_episode_steps": 0}, "max_episode_steps"),
        ({"render_mode": "ansi"}, "render_mode"),
        ({"lidar_noise_std": -0.1}, "lidar_noise_std"),
        ({"lidar_frames": 0}, "lidar_frames must be an int in"),
        ({"lidar_frames": 5}, "lidar_frames must be an int in"),
        ({"lidar_frames": 2.0}, "lidar_frames must be an int in"),
        ({"lidar_frame_ticks": 0}, "lidar_frame_ticks must be an int in"),
        ({"action_repeat": 0}, "action_repeat must be an int in"),
        ({"action_repeat": 11}, "action_repeat must be an int in"),
    ],
)
def test_bad_constructor_arguments_raise(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        MultiRobotNavEnv(**kwargs)


@pytest.mark.parametrize("action", [20, -1, 2.5, "a", None, np.array([1, 2])])
def test_bad_action_raises(action: Any) -> None:
    env = MultiRobotNavEnv(2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"\[0, 19\]"):
        env.step({"robot_0": action, "robot_1": 0})
    single = SingleRobotNavEnv()
    single.reset(seed=0)
    with pytest.raises(ValueError, match=r"\[0, 19\]"):
        single.step(action)
    env.close()
    single.close()


def test_accepted_action_types() -> None:
    env = MultiRobotNavEnv(2)
    env.reset(seed=0)
    env.step({"robot_0": np.int64(3), "robot_1": 4.0})
    env.step({"robot_0": np.array(3), "robot_1": np.array([4])})
    env.close()


def test_missing_action_raises() -> None:
    env = MultiRobotNavEnv(2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="robot_1"):
        env.step({"robot_0": 2})
    env.close()


@pytest.mark.parametrize(
    "options",
    [
        {"start_poses": np.zeros((3, 3))},
        {"start_poses": [[0, 0, 0], [9.0, 0, 0]]},
        {"targets": np.zeros((2, 3))},
        {"targets": [[0, 0], [np.nan, 0]]},
        {"start_poses": "here"},
    ],
)
def test_bad_reset_options_raise(options: dict[str, Any]) -> None:
    env = MultiRobotNavEnv(2)
    with pytest.raises(ValueError, match="options"):
        env.reset(seed=0, options=options)
    env.close()


def test_bad_target_set_raises() -> None:
    env = MultiRobotNavEnv(4, scenario="unseen")
    with pytest.raises(ValueError, match="target_set"):
        env.reset(options={"target_set": 99})
    env.close()


def test_unknown_agent_raises() -> None:
    env = MultiRobotNavEnv(2)
    with pytest.raises(ValueError, match="robot_7"):
        env.observation_space("robot_7")
    env.close()


# --- rendering -------------------------------------------------------------------------------------------


def test_rgb_array_picture_and_gif(tmp_path: Any) -> None:
    env = MultiRobotNavEnv(4, render_mode="rgb_array", render_lidar=True)
    env.reset(seed=0)
    frames = [env.render()]
    for _ in range(3):
        env.step(dict.fromkeys(env.agents, 17))
        frames.append(env.render())
    assert all(frame.shape == frames[0].shape and frame.dtype == np.uint8 for frame in frames)
    assert not np.array_equal(frames[0], frames[-1])  # the robots moved
    path = save_gif(frames, tmp_path / "sub" / "run.gif", fps=10)
    assert path.stat().st_size > 0
    with pytest.raises(ValueError, match="frame"):
        save_gif([], tmp_path / "empty.gif")
    env.close()


def test_render_without_mode_returns_none() -> None:
    env = MultiRobotNavEnv(2)
    env.reset(seed=0)
    assert env.render() is None
    env.close()


def test_human_mode_without_display_raises(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    with pytest.raises(RuntimeError, match="display"):
        MultiRobotNavEnv(2, render_mode="human")


def test_pictures_script(tmp_path: Any) -> None:
    from envs.turtlebot3 import pictures

    written = pictures.run(tmp_path, n_forward_ticks=2)
    assert [path.name for path in written] == [
        "multi_robot_4.png",
        "single_robot.png",
        "unseen_4.png",
        "blocks_4.png",
        "rooms.png",
    ]
    assert all(path.stat().st_size > 1000 for path in written)


def test_gui_visuals_build() -> None:
    """The shapes the GUI shows, built in DIRECT mode (no display needed) so a typo cannot hide there."""
    env = MultiRobotNavEnv(2)
    env.reset(seed=0)
    world = env.world
    world.gui = True
    assert world._robot_visual(1) >= 0
    world._add_map_visuals()
    world.show_targets(env._targets)
    world.show_targets(env._targets)  # replaces the markers
    assert len(world._target_ids) == 2
    env.close()
    env = MultiRobotNavEnv(2, scenario="blocks")
    env.reset(seed=0)
    env.world.gui = True
    env.world.set_blocks(env.layout.obstacles)  # the map's boxes and the blocks, drawn in place of the last ones
    assert len(env.world._map_visual_ids) == len(env.layout.boxes)
    env.world.set_blocks(env.layout.obstacles[:1])
    assert len(env.world._map_visual_ids) == len(env.layout.walls) + 1
    env.close()


def test_a_team_world_as_one_gymnasium_env() -> None:
    """TeamAsGymnasium (EPS's team worlds): stacked observations, one action per robot, the mean reward, the end of
    the world's episode (a time limit: truncated, no success) with the team's record."""
    from sb3_eps.common.parallel_wrappers import TeamAsGymnasium

    env = TeamAsGymnasium(MultiRobotNavEnv(n_robots=2, max_episode_steps=5))
    try:
        obs, _ = env.reset(seed=0)
        assert obs.shape == (2, 30) and env.observation_space.contains(obs)
        assert env.action_space.nvec.tolist() == [20, 20]
        with pytest.raises(ValueError, match="one per agent"):
            env.step(np.zeros(3, dtype=np.int64))
        for tick in range(5):
            obs, reward, terminated, truncated, info = env.step(np.zeros(2, dtype=np.int64))  # stand still
            assert np.isclose(reward, -0.005)
            if tick < 4:
                assert not (terminated or truncated) and info == {}
        assert truncated and not terminated
        assert info["is_success"] is False and info["team"]["ticks"] == 5
    finally:
        env.close()


def test_stacked_scans_are_the_scans_of_earlier_ticks() -> None:
    """``lidar_frames=3, lidar_frame_ticks=2``: the first 30 floats are the one-scan observation, then the scans of 2
    and 4 ticks ago (the first scan while the episode is younger), for every robot, parked ones aside."""
    single_scan = MultiRobotNavEnv(n_robots=4)
    stacked = MultiRobotNavEnv(n_robots=4, lidar_frames=3, lidar_frame_ticks=2)
    assert single_scan.observation_space("robot_0").shape == (30,)
    space = stacked.observation_space("robot_0")
    assert space.shape == (86,) and space.low[29] == -1.0 and (space.low[30:] == 0.0).all()
    plain, _ = single_scan.reset(seed=5)
    obs, _ = stacked.reset(seed=5)
    history = {agent: [o[:28]] for agent, o in obs.items()}
    for agent in obs:
        np.testing.assert_array_equal(obs[agent][:30], plain[agent])
        np.testing.assert_array_equal(obs[agent][30:58], obs[agent][:28])
        np.testing.assert_array_equal(obs[agent][58:], obs[agent][:28])
    rng = np.random.default_rng(0)
    moved = False
    for _ in range(40):
        actions = {agent: int(rng.integers(20)) for agent in stacked.agents}
        plain, *_ = single_scan.step(actions)
        obs, *_ = stacked.step(actions)
        for agent, o in obs.items():
            np.testing.assert_array_equal(o[:30], plain[agent])  # the option adds scans, changes nothing else
            history[agent].append(o[:28])
            scans = history[agent]
            np.testing.assert_array_equal(o[30:58], scans[max(len(scans) - 3, 0)])
            np.testing.assert_array_equal(o[58:86], scans[max(len(scans) - 5, 0)])
            moved |= not np.array_equal(o[:28], o[58:86])
        if not stacked.agents:
            break
    assert moved, "the stacked scans never differed from the current one"
    assert SingleRobotNavEnv(lidar_frames=2).observation_space.shape == (58,)
    single_scan.close()
    stacked.close()


def test_action_repeat_holds_each_action_for_its_ticks() -> None:
    """``action_repeat=4``: one step is four ticks of the one-tick world with the same actions, rewards summed, and a
    robot that ends inside a step reports the tick it ended (here, every robot of a team that collides)."""
    held = MultiRobotNavEnv(n_robots=4, action_repeat=4, max_episode_steps=200)
    ticked = MultiRobotNavEnv(n_robots=4, max_episode_steps=200)
    held.reset(seed=3)
    ticked.reset(seed=3)
    rng = np.random.default_rng(1)
    steps = 0
    while held.agents:
        actions = {agent: int(rng.integers(20)) for agent in held.agents}
        obs, rewards, terminations, truncations, infos = held.step(actions)
        expected_rewards = dict.fromkeys(actions, 0.0)
        last: dict[str, tuple[Any, ...]] = {}
        for _ in range(4):
            if not ticked.agents:
                break
            tick = ticked.step({agent: actions[agent] for agent in ticked.agents})
            for agent in tick[0]:
                expected_rewards[agent] += tick[1][agent]
                last[agent] = (tick[0][agent], tick[2][agent], tick[3][agent], tick[4][agent]["arrived"])
        assert rewards == pytest.approx(expected_rewards) and set(last) == set(obs)
        for agent, (observation, terminated, truncated, arrived) in last.items():
            np.testing.assert_array_equal(obs[agent], observation)
            assert (terminations[agent], truncations[agent], infos[agent]["arrived"]) == (terminated, truncated, arrived)
        assert held.agents == ticked.agents
        assert held._ticks == ticked._ticks and infos[next(iter(infos))]["team"] == ticked._team_info()
        steps += 1
    assert not ticked.agents and held._ticks > 4 * (steps - 1)
    held.close()
    ticked.close()


def test_lidar_range_caps_and_rescales_the_scan_only() -> None:
    """``lidar_range=1``: the policy sees every range capped at 1 m and divided by 1 m; the world (poses, rewards,
    collisions) is the full-range world's, tick by tick, and out-of-range values are refused in one line."""
    near = MultiRobotNavEnv(n_robots=4, lidar_range=1.0, max_episode_steps=100)
    full = MultiRobotNavEnv(n_robots=4, max_episode_steps=100)
    obs_near, _ = near.reset(seed=5)
    obs_full, _ = full.reset(seed=5)
    rng = np.random.default_rng(2)
    seen_capped = False
    while full.agents:
        for agent in obs_full:
            ranges = obs_full[agent][:28] * 3.5
            np.testing.assert_allclose(obs_near[agent][:28], np.minimum(ranges, 1.0), atol=1e-5)
            np.testing.assert_array_equal(obs_near[agent][28:], obs_full[agent][28:])
            seen_capped |= bool((ranges > 1.0).any() and (obs_near[agent][:28] == 1.0).any())
        actions = {agent: int(rng.integers(20)) for agent in full.agents}
        obs_near, rewards_near, *_ = near.step(actions)
        obs_full, rewards_full, *_ = full.step(actions)
        assert rewards_near == rewards_full and near.agents == full.agents
    assert seen_capped and near.observation_space("robot_0") == full.observation_space("robot_0")
    for bad in (0.5, 4.0, True, "2"):
        with pytest.raises(ValueError, match="lidar_range must be a number of metres in"):
            MultiRobotNavEnv(n_robots=2, lidar_range=bad)
    near.close()
    full.close()
