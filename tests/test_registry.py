"""The env registry: ids, constructors, gymnasium registration, EPS counterparts and its error messages."""

import gymnasium
import pytest
from pettingzoo import ParallelEnv

import envs


def test_ids_are_partitioned() -> None:
    assert set(envs.MULTI_AGENT_ENV_IDS) == {
        "MultiRobotNav-2-v0",
        "MultiRobotNav-4-v0",
        "MultiRobotNav-8-v0",
        "MultiRobotNav-12-v0",
        "MultiRobotNav-24-v0",
        *(f"MultiRobotNavRooms-{n}{suffix}-v0" for n in (4, 8, 12, 24) for suffix in ("", "-validation", "-test")),
        *(f"MultiRobotNavMixed-{n}-v0" for n in (4, 8, 12, 24)),
        "MultiRobotNavUnseen-4-v0",
        "MultiRobotNavUnseen-4-varied-v0",
        "MultiRobotNavBlocks-12-v0",
        "CooperativeNavigation-v0",
    }
    assert set(envs.SINGLE_AGENT_ENV_IDS) == {"SingleRobotNav-v0", "CooperativeNavigationSingle-v0"}
    assert envs.DEBUG_ENV_IDS == ("Corridor-1-v0", "Corridor-2-v0", "Corridor-3-v0", "Corridor-4-v0")
    assert envs.ENV_IDS == envs.MULTI_AGENT_ENV_IDS + envs.SINGLE_AGENT_ENV_IDS + envs.DEBUG_ENV_IDS
    assert all(envs.is_multi_agent(env_id) for env_id in envs.MULTI_AGENT_ENV_IDS + envs.DEBUG_ENV_IDS)
    assert not any(envs.is_multi_agent(env_id) for env_id in envs.SINGLE_AGENT_ENV_IDS)


def test_make_cooperative_navigation() -> None:
    env = envs.make_parallel_env("CooperativeNavigation-v0", max_cycles=5)
    assert isinstance(env, ParallelEnv)
    assert env.metadata["name"] == "cooperative_navigation_v0"
    assert env.possible_agents == ["agent_0", "agent_1", "agent_2"]
    single = envs.make_single_env("CooperativeNavigationSingle-v0")
    assert isinstance(single, gymnasium.Env)
    assert single.observation_space.shape == env.observation_space("agent_0").shape == (18,)


@pytest.mark.parametrize(
    ("env_id", "n_robots", "scenario"),
    [("MultiRobotNav-2-v0", 2, "arena"), ("MultiRobotNavUnseen-4-v0", 4, "unseen")],
)
def test_make_robot_worlds(env_id: str, n_robots: int, scenario: str) -> None:
    env = envs.make_parallel_env(env_id)
    try:
        assert len(env.possible_agents) == n_robots
        assert env.scenario == scenario
    finally:
        env.close()


@pytest.mark.parametrize("env_id", ["SingleRobotNav-v0", "CooperativeNavigationSingle-v0"])
def test_single_agent_ids_are_gymnasium_ids(env_id: str) -> None:
    env = gymnasium.make(env_id)
    try:
        obs, _ = env.reset(seed=0)
        assert env.observation_space.contains(obs)
    finally:
        env.close()


def test_debug_corridor_ids() -> None:
    env = envs.make_parallel_env("Corridor-3-v0")
    assert len(env.possible_agents) == 3
    with pytest.raises(ValueError, match="multi-agent env"):
        envs.make_single_env("Corridor-3-v0")


@pytest.mark.parametrize("call", [envs.make_parallel_env, envs.make_single_env, envs.is_multi_agent])
def test_unknown_id_lists_the_known_ids(call) -> None:
    with pytest.raises(ValueError, match="unknown env id 'Nope-v0'") as error:
        call("Nope-v0")
    assert all(env_id in str(error.value) for env_id in envs.ENV_IDS)


def test_wrong_kind_of_id_names_the_right_function() -> None:
    with pytest.raises(ValueError, match=r"single-agent env: build it with envs.make_single_env"):
        envs.make_parallel_env("CooperativeNavigationSingle-v0")
    with pytest.raises(ValueError, match=r"multi-agent env: build it with envs.make_parallel_env"):
        envs.make_single_env("CooperativeNavigation-v0")


def test_the_id_fixes_its_team_size() -> None:
    with pytest.raises(ValueError, match="fixes n_robots=4"):
        envs.make_parallel_env("MultiRobotNav-4-v0", n_robots=8)


@pytest.mark.parametrize("env_id", envs.MULTI_AGENT_ENV_IDS + envs.DEBUG_ENV_IDS)
def test_pettingzoo_make_builds_every_multi_agent_id(env_id: str) -> None:
    """PettingZoo's own registry (``pettingzoo.make("parallel", id)``) knows every id once ``envs`` is imported."""
    import pettingzoo

    env, direct = pettingzoo.make("parallel", env_id), envs.make_parallel_env(env_id)
    try:
        assert type(env) is type(direct) and env.possible_agents == direct.possible_agents
    finally:
        env.close()
        direct.close()
    # The id's fixed arguments hold there too.
    if env_id.startswith("MultiRobotNav-"):
        with pytest.raises(ValueError, match="fixes n_robots"):
            pettingzoo.make("parallel", env_id, n_robots=3)


@pytest.mark.parametrize("env_id", ["MultiRobotNav-2-v0", "CooperativeNavigation-v0", "Corridor-2-v0"])
def test_registered_worlds_pass_pettingzoo_parallel_api_test(env_id: str) -> None:
    import pettingzoo
    from pettingzoo.test import parallel_api_test

    env = pettingzoo.make("parallel", env_id)
    try:
        parallel_api_test(env, num_cycles=50)
    finally:
        env.close()
