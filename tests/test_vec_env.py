"""The SB3 bridge (make_vec_env / MultiAgentVecEnv): SB3 compatibility, seeding, per-agent ends, team episodes."""

from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo import ParallelEnv
from stable_baselines3 import DQN
from stable_baselines3.common.callbacks import BaseCallback

import envs
from sb3_eps import MultiAgentVecEnv, make_vec_env
from sb3_eps.common.subproc_vec_env import SubprocMultiAgentVecEnv

TINY_DQN = {
    "policy_kwargs": {"net_arch": [16]},
    "learning_starts": 100,
    "buffer_size": 5_000,
    "batch_size": 16,
}


class ParkingEnv(ParallelEnv):
    """A tiny deterministic world whose agents end at chosen ticks, as robots that arrive and park.

    Observation of agent i: ``[i, tick]``. Agent i terminates at tick ``arrive_at[i]`` (None: never) with reward 1,
    otherwise -0.1 per tick; the world is truncated after ``max_cycles`` ticks.
    """

    metadata = {"name": "parking_v0"}

    def __init__(self, arrive_at: tuple[int | None, ...] = (2, 4, None), max_cycles: int = 6) -> None:
        self.arrive_at = arrive_at
        self.max_cycles = max_cycles
        self.possible_agents = [f"agent_{i}" for i in range(len(arrive_at))]
        self.agents: list[str] = []
        self.render_mode = None
        self.state_space = spaces.Box(0.0, 100.0, (len(arrive_at),), np.float32)
        self._observation_space = spaces.Box(0.0, 100.0, (2,), np.float32)
        self._action_space = spaces.Discrete(3)
        self.tick = 0

    def observation_space(self, agent: str) -> spaces.Space:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Space:
        return self._action_space

    def _obs(self, agent: str) -> np.ndarray:
        return np.array([self.possible_agents.index(agent), self.tick], dtype=np.float32)

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        self.tick = 0
        self.agents = list(self.possible_agents)
        return {a: self._obs(a) for a in self.agents}, {a: {"reset": True} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        assert set(actions) == set(self.agents), "only live agents may act"
        self.tick += 1
        arrived = {a: self.arrive_at[self.possible_agents.index(a)] == self.tick for a in self.agents}
        truncated = self.tick >= self.max_cycles
        team = {"success": all(t is not None and t <= self.tick for t in self.arrive_at), "ticks": self.tick}
        result = (
            {a: self._obs(a) for a in self.agents},
            {a: 1.0 if arrived[a] else -0.1 for a in self.agents},
            dict(arrived),
            {a: truncated and not arrived[a] for a in self.agents},
            {a: {"team": team} for a in self.agents},
        )
        self.agents = [a for a in self.agents if not arrived[a] and not truncated]
        return result

    def state(self) -> np.ndarray:
        return np.full(len(self.possible_agents), self.tick, dtype=np.float32)


@pytest.fixture(params=["dummy", "subproc"])
def mode(request) -> str:
    """Every contract test runs with the worlds in process (dummy) and in worker processes (subproc)."""
    return request.param


@pytest.fixture
def make(mode):
    """``make_vec_env`` in the test's mode; the vec envs it made are closed afterwards."""
    made = []

    def build(*args, **kwargs):
        made.append(make_vec_env(*args, vec_env_cls=mode, **kwargs))
        return made[-1]

    yield build
    for venv in made:
        venv.close()


@pytest.fixture
def bridge(mode):
    """``MultiAgentVecEnv(env_fns)``, or its worker-process twin, in the test's mode."""
    made = []

    def build(env_fns):
        made.append(MultiAgentVecEnv(env_fns) if mode == "dummy" else SubprocMultiAgentVecEnv(env_fns))
        return made[-1]

    yield build
    for venv in made:
        venv.close()


def run(venv: MultiAgentVecEnv, n_steps: int, seed: int = 0) -> list:
    rng = np.random.default_rng(seed)
    record = [venv.reset()]
    for _ in range(n_steps):
        obs, rewards, dones, _ = venv.step(rng.integers(venv.action_space.n, size=venv.num_envs))
        record.append((obs, rewards, dones, venv.get_state().copy()))
    return record


def assert_records_equal(a: list, b: list) -> None:
    for x, y in zip(a, b, strict=True):
        for u, v in zip(x if isinstance(x, tuple) else (x,), y if isinstance(y, tuple) else (y,), strict=True):
            np.testing.assert_array_equal(u, v)


# --- bad input ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"env_id": "Nope-v0"}, "unknown env id 'Nope-v0'; multi-agent ids"),
        ({"env_id": 3}, "env_id must be a registered id"),
        (
            {"env_id": "CooperativeNavigation-v0", "n_envs": 0},
            r"n_envs \(the number of worlds\) must be an int >= 1",
        ),
        ({"env_id": "CooperativeNavigation-v0", "n_envs": 1.5}, "n_envs"),
        ({"env_id": "CooperativeNavigation-v0", "n_envs": True}, "n_envs"),
        ({"env_id": "CooperativeNavigation-v0", "seed": "0"}, "seed must be None or a non-negative int"),
        ({"env_id": "CooperativeNavigation-v0", "seed": -1}, "seed must be None or a non-negative int"),
        ({"env_id": "CooperativeNavigation-v0", "seed": 1.0}, "seed must be None or a non-negative int"),
    ],
)
def test_bad_input_raises_value_error(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make_vec_env(**kwargs)


def test_bad_seed_and_actions_on_the_vec_env() -> None:
    venv = make_vec_env("CooperativeNavigation-v0")
    with pytest.raises(ValueError, match="seed must be None"):
        venv.seed("1")
    venv.reset()
    with pytest.raises(ValueError, match=r"one action per sub-env \(1 worlds x 3 agents = 3\)"):
        venv.step(np.zeros(2, dtype=np.int64))


# --- layout and SB3 ------------------------------------------------------------------------------------------------


def test_layout_and_attributes(make) -> None:
    venv = make("CooperativeNavigation-v0", n_envs=2, seed=0)
    assert (venv.n_agents, venv.n_worlds, venv.num_envs) == (3, 2, 6)
    assert venv.env_id == "CooperativeNavigation-v0"
    assert venv.possible_agents == ["agent_0", "agent_1", "agent_2"]
    assert venv.state_space.shape == (54,)
    obs = venv.reset()
    assert obs.shape == (6, 18) and obs.dtype == np.float32
    assert venv.get_state().shape == (2, 54)
    # mpe2's state is the concatenated observations: world-major order puts agent i of world w at w * 3 + i.
    np.testing.assert_array_equal(venv.get_state(), obs.reshape(2, 54))
    assert venv.get_attr("render_mode") == [None] * 6
    assert venv.get_attr("max_cycles", indices=[0, 4]) == [25, 25]
    venv.set_attr("max_cycles", 7, indices=[3])
    assert venv.get_attr("max_cycles") == [25, 25, 25, 7, 7, 7]
    states = venv.env_method("state", indices=[1, 2, 3])
    np.testing.assert_array_equal(states[0], states[1])
    np.testing.assert_array_equal(states[2], venv.get_state()[1])
    assert venv.env_is_wrapped(object) == [False] * 6


def test_render_one_picture_per_world(make) -> None:
    venv = make("CooperativeNavigation-v0", n_envs=2, env_kwargs={"render_mode": "rgb_array"})
    venv.reset()
    images = venv.get_images()
    assert len(images) == 2
    picture = venv.render()
    assert picture.ndim == 3 and picture.dtype == np.uint8 and picture.shape[0] == 2 * images[0].shape[0]
    venv.close()


def test_dqn_learns_with_timeouts_and_one_episode_per_world(make) -> None:
    venv = make("CooperativeNavigation-v0", n_envs=2)
    model = DQN("MlpPolicy", venv, seed=0, **TINY_DQN)
    model.learn(2_000)
    ticks = model.num_timesteps // venv.n_agents  # summed over the worlds
    assert ticks == venv.total_ticks
    finished_worlds = venv.n_worlds * (ticks // venv.n_worlds // 25)
    assert len(model.ep_info_buffer) == finished_worlds > 0
    assert all(info["l"] == 25 and {"success", "collision", "n_collisions"} <= info.keys() for info in model.ep_info_buffer)
    assert len(model.ep_success_buffer) == finished_worlds
    # Every MPE episode ends by its time limit: each stored done is a timeout, so DQN bootstraps through it.
    stored = slice(0, model.replay_buffer.pos)
    dones, timeouts = model.replay_buffer.dones[stored], model.replay_buffer.timeouts[stored]
    assert dones.sum() == finished_worlds * venv.n_agents
    np.testing.assert_array_equal(timeouts, dones)


def test_single_agent_ids_give_one_agent_worlds(make) -> None:
    venv = make("CooperativeNavigationSingle-v0", n_envs=2, seed=0)
    assert (venv.n_agents, venv.num_envs) == (1, 2)
    obs = venv.reset()
    np.testing.assert_array_equal(venv.get_state(), obs)  # no state(): the observation stands in
    assert venv.get_attr("max_cycles") == [25, 25]  # the gymnasium env's own attribute
    model = DQN("MlpPolicy", venv, seed=0, **TINY_DQN)
    model.learn(200)
    assert len(model.ep_info_buffer) == 2 * (model.num_timesteps // 2 // 25)
    assert model.ep_info_buffer[0]["l"] == 25 and "is_success" not in model.ep_info_buffer[0]


# --- seeding -----------------------------------------------------------------------------------------------------


def test_seeded_runs_are_identical(make) -> None:
    first = run(make("CooperativeNavigation-v0", n_envs=2, seed=3), 60)
    again = run(make("CooperativeNavigation-v0", n_envs=2, seed=3), 60)
    other = run(make("CooperativeNavigation-v0", n_envs=2, seed=4), 60)
    assert_records_equal(first, again)
    with pytest.raises(AssertionError):
        assert_records_equal(first, other)


def test_world_w_is_seeded_with_seed_plus_w(make) -> None:
    two_worlds = make("CooperativeNavigation-v0", n_envs=2, seed=10)
    assert two_worlds.seed(10) == [10, 10, 10, 11, 11, 11]
    obs = two_worlds.reset()
    np.testing.assert_array_equal(obs[3:], make("CooperativeNavigation-v0", seed=11).reset())
    # A seed is used once: the next reset continues the worlds' random streams.
    assert not np.array_equal(two_worlds.reset(), obs)


def test_sb3_seed_argument_seeds_the_worlds(make) -> None:
    observations = []
    for _ in range(2):
        model = DQN("MlpPolicy", make("CooperativeNavigation-v0", n_envs=2), seed=7, **TINY_DQN)
        model.learn(300)
        observations.append(model.replay_buffer.observations[: model.replay_buffer.pos].copy())
    np.testing.assert_array_equal(*observations)


# --- per-agent ends, alive flags, terminal values, team episodes ----------------------------------------------------


def test_agents_that_end_early(bridge) -> None:
    venv = bridge([ParkingEnv] * 2)
    assert (venv.n_agents, venv.n_worlds) == (3, 2)
    venv.reset()
    assert venv.reset_infos[0] == {"reset": True}
    actions = np.zeros(6, dtype=np.int64)
    history = [(*venv.step(actions), venv.alive.copy()) for _ in range(6)]
    obs, rewards, dones, infos, alive = history[1]  # tick 2: agent 0 of each world arrives
    assert list(dones) == [True, False, False] * 2
    assert alive.all() and infos[0]["alive"] and not infos[0]["TimeLimit.truncated"]
    np.testing.assert_array_equal(infos[0]["terminal_observation"], [0, 2])
    np.testing.assert_array_equal(obs[0], [0, 2])
    assert "episode" not in infos[0]
    for tick in (3, 4, 5):  # agent 0 is parked: last observation, reward 0, not alive, not done
        obs, rewards, dones, infos, alive = history[tick - 1]
        assert not infos[0]["alive"] and not alive[0] and not alive[3]
        assert not dones[0] and rewards[0] == 0.0
        np.testing.assert_array_equal(obs[0], [0, 2])
    assert list(history[4][4]) == [False, False, True] * 2  # tick 5: agent 1 parked too
    obs, rewards, dones, infos, _ = history[3]  # tick 4: agent 1 arrives
    assert dones[1] and infos[1]["alive"] and rewards[1] == 1.0
    obs, rewards, dones, infos, _ = history[5]  # tick 6: the time limit ends the world
    assert dones.all()
    assert [info["alive"] for info in infos[:3]] == [False, False, True]
    assert [info["TimeLimit.truncated"] for info in infos[:3]] == [False, False, True]
    for i, tick in enumerate((2, 4, 6)):
        np.testing.assert_array_equal(infos[i]["terminal_observation"], [i, tick])
        np.testing.assert_array_equal(obs[i], [i, 0])  # the new episode
    for w in (0, 1):
        first = infos[3 * w]
        assert first["episode"]["r"] == pytest.approx(0.9 + 0.7 - 0.6)  # the three agents' returns
        assert first["episode"]["l"] == 6 and first["is_success"] is False
        np.testing.assert_array_equal(first["terminal_state"], [6, 6, 6])
        assert all("episode" not in info and "terminal_state" not in info for info in infos[3 * w + 1 : 3 * w + 3])
    np.testing.assert_array_equal(venv.get_state(), np.zeros((2, 3)))
    venv.step(actions)  # every agent acts again in the new episode
    assert venv.alive.all()


def test_world_ends_when_every_agent_arrived(bridge) -> None:
    venv = bridge([lambda: ParkingEnv(arrive_at=(1, 3), max_cycles=10)])
    venv.reset()
    steps = [venv.step(np.zeros(2, dtype=np.int64)) for _ in range(3)]
    _, _, dones, infos = steps[2]
    assert dones.all() and [info["alive"] for info in infos] == [False, True]
    assert not any(info["TimeLimit.truncated"] for info in infos)
    assert infos[0]["episode"]["l"] == 3 and infos[0]["is_success"] is True
    assert infos[0]["episode"]["r"] == pytest.approx(1.0 - 0.1 - 0.1 + 1.0)


# --- the TurtleBot3 worlds ---------------------------------------------------------------------------------------

STAND_STILL = 2  # MultiRobotNav's action (v, w) = (0, 0)


class StepRecorder(BaseCallback):
    """Keeps the dones and infos of every rollout step."""

    def __init__(self) -> None:
        super().__init__()
        self.steps: list[tuple[np.ndarray, list[dict]]] = []

    def _on_step(self) -> bool:
        self.steps.append((self.locals["dones"].copy(), self.locals["infos"]))
        return True


def test_dqn_on_four_robots(make) -> None:
    venv = make("MultiRobotNav-4-v0", n_envs=2, env_kwargs={"max_episode_steps": 40})
    recorder = StepRecorder()
    model = DQN("MlpPolicy", venv, seed=0, **TINY_DQN)
    model.learn(2_000, callback=recorder)
    world_ends = sum(int(dones.reshape(2, 4).all(axis=1).sum()) for dones, _ in recorder.steps)
    assert len(model.ep_info_buffer) == world_ends > 0
    assert all({"success", "collision", "n_arrived"} <= info.keys() for info in model.ep_info_buffer)
    # The buffer's timeouts are exactly the truncations the bridge reported (collisions are terminations).
    expected = np.array([[info.get("TimeLimit.truncated", False) for info in infos] for _, infos in recorder.steps])
    np.testing.assert_array_equal(model.replay_buffer.timeouts[: model.replay_buffer.pos], expected)


def test_an_arrived_robot_parks_until_its_world_resets(make) -> None:
    venv = make("MultiRobotNav-4-v0", env_kwargs={"max_episode_steps": 4})
    starts = [(-1.0, -1.0, 0.0), (1.0, -1.0, 0.0), (-1.0, 1.0, 0.0), (1.0, 1.0, 0.0)]
    # Robot 0's target lies within the 0.1 m arrival radius: it arrives on the first tick.
    targets = [(-0.95, -1.0), (1.0, 0.5), (-1.0, 0.2), (0.2, 1.0)]
    venv.set_options({"start_poses": starts, "targets": targets})
    venv.reset()
    actions = np.full(4, STAND_STILL)
    obs, rewards, dones, infos = venv.step(actions)
    assert list(dones) == [True, False, False, False] and rewards[0] == 1.0
    assert infos[0]["alive"] and infos[0]["arrived"] and not infos[0]["TimeLimit.truncated"]
    terminal = infos[0]["terminal_observation"]
    np.testing.assert_array_equal(terminal, obs[0])
    for _ in range(2):
        obs, rewards, dones, infos = venv.step(actions)
        assert list(venv.alive) == [False, True, True, True] and not dones.any()
        assert rewards[0] == 0.0 and infos[0] == {"alive": False}
        np.testing.assert_array_equal(obs[0], terminal)
    obs, rewards, dones, infos = venv.step(actions)  # tick 4: the time limit
    assert dones.all() and list(venv.alive) == [False, True, True, True]
    assert [info["TimeLimit.truncated"] for info in infos] == [False, True, True, True]
    np.testing.assert_array_equal(infos[0]["terminal_observation"], terminal)
    episode = infos[0]["episode"]
    assert episode["l"] == 4 and episode["n_arrived"] == 1 and episode["success"] is False
    assert episode["r"] == pytest.approx(1.0 - 3 * 4 * 0.005)
    assert infos[0]["is_success"] is False
    terminal_state = infos[0]["terminal_state"].reshape(4, 9)
    assert list(terminal_state[:, 8]) == [1.0, 0.0, 0.0, 0.0]  # the "arrived" field of the global state
    assert venv.get_state().shape == (1, 36) and venv.get_state()[0, 8] == 0.0  # the new episode
    venv.close()


def test_worlds_without_state_get_the_concatenated_observations(bridge) -> None:
    def no_state_env() -> ParkingEnv:
        env = ParkingEnv()
        del env.state_space
        return env

    venv = bridge([no_state_env])
    assert venv.state_space.shape == (6,)
    obs = venv.reset()
    np.testing.assert_array_equal(venv.get_state(), obs.reshape(1, 6))
    venv.step(np.zeros(3, dtype=np.int64))
    obs, _, _, _ = venv.step(np.zeros(3, dtype=np.int64))  # agent 0 arrived: its last observation stays
    np.testing.assert_array_equal(venv.get_state(), obs.reshape(1, 6))


# --- env ids through the registries -------------------------------------------------------------------------------


def test_env_ids_resolve_through_pettingzoo_and_gymnasium_registries() -> None:
    """The core knows no world: an id registered with PettingZoo builds a multi-agent world, one registered with
    gymnasium one-agent worlds; the worlds of this project register theirs when `envs` is imported."""
    import gymnasium
    import pettingzoo

    from sb3_eps.common.vec_env import world_constructor

    make, kwargs, multi_agent = world_constructor("MultiRobotNav-2-v0")
    assert multi_agent and kwargs == {} and make.func is envs.make_parallel_env  # type: ignore[attr-defined]
    make, kwargs, multi_agent = world_constructor("SingleRobotNav-v0")
    assert not multi_agent and make is envs.turtlebot3.SingleRobotNavEnv
    assert "Corridor-2-v0" in pettingzoo.parallel_registry and "SingleRobotNav-v0" in gymnasium.registry
    venv = make_vec_env("Corridor-2-v0", n_envs=2, seed=0)
    try:
        assert (venv.n_worlds, venv.n_agents, venv.env_id) == (2, 2, "Corridor-2-v0")
    finally:
        venv.close()
    with pytest.raises(ValueError, match=r"unknown env id 'Nope-v0'; multi-agent ids: .*'MultiRobotNav-4-v0'"):
        world_constructor("Nope-v0")


def test_a_world_registered_with_pettingzoo_under_a_string_entry_point_builds() -> None:
    import pettingzoo

    env_id = "StringEntryCorridor-v0"
    if env_id not in pettingzoo.parallel_registry:
        pettingzoo.register("parallel", env_id, entry_point="envs.debug:CorridorEnv", kwargs={"n_agents": 3})
    venv = make_vec_env(env_id, n_envs=1, seed=0)
    try:
        assert venv.n_agents == 3 and venv.env_id == env_id
    finally:
        venv.close()
