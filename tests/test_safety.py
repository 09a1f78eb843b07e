"""The lidar action mask built into a policy (``policy_kwargs.safety_margin``, ``sb3_eps.common.safety``): the same
geometry as the ONNX runner's layer, the actions it plays, explores and bootstraps from, its place in a saved and an
exported model, EPS's mutants acting through it, and its one-line error for a world without a lidar."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch as th

import envs  # noqa: F401  (registers the worlds)
from envs.turtlebot3.deployment import deployment_description
from envs.turtlebot3.robot import N_ACTIONS, N_BEAMS, ROBOT_RADIUS
from sb3_eps import GDQ, IQL, make_vec_env
from sb3_eps.common.safety import LidarSafetyMask, safety_geometry
from sb3_eps.common.utils import epsilon_greedy
from sb3_eps.eps.evaluation import EvaluationBlock

SHORT_VIEW = {"action_repeat": 4, "lidar_range": 1.0}
FULL_AHEAD, STAND_STILL = 17, 2
MARGIN = 0.03


def wall_ahead(n: int, distance: float) -> np.ndarray:
    """``n`` observations (1 m view) of a wall ``distance`` metres ahead of the robot's centre, nothing else in view."""
    obs = np.ones((n, N_BEAMS + 2), dtype=np.float32)
    obs[:, N_BEAMS // 2 - 2 : N_BEAMS // 2 + 2] = distance  # the four beams within 18 degrees of straight ahead
    obs[:, N_BEAMS:] = 0.5
    return obs


@pytest.fixture(scope="module")
def mask() -> LidarSafetyMask:
    return LidarSafetyMask(MARGIN, safety_geometry(deployment_description(**SHORT_VIEW)))


def test_the_mask_measures_what_the_onnx_runner_measures(mask: LidarSafetyMask) -> None:
    pytest.importorskip("onnxruntime")
    from sb3_eps.deploy.onnx_runner import lidar_clearance, swept_arcs

    geometry = safety_geometry(deployment_description(**SHORT_VIEW))
    rng = np.random.default_rng(0)
    scan = rng.uniform(0.12, 1.0, size=(500, N_BEAMS)).astype(np.float32)
    scan[rng.random(scan.shape) < 0.3] = 1.0  # beams that hit nothing
    scan[:5] = 1.0  # rows that see nothing at all
    obs = np.concatenate([scan, np.zeros((500, 2), np.float32)], axis=1)
    arcs = swept_arcs(np.array(geometry["linear_m_s"]), np.array(geometry["angular_rad_s"]), 0.2)
    expected = lidar_clearance(scan, 1.0, np.array(geometry["angles_rad"]), arcs, ROBOT_RADIUS)
    measured = mask.clearance(th.as_tensor(obs)).numpy()
    seen = np.isfinite(expected)
    np.testing.assert_allclose(measured[seen], expected[seen], atol=1e-5)
    assert (~seen[:5]).all() and (measured[~seen] > 100).all()  # nothing seen: far clear, every action allowed


def test_a_wall_ahead_blocks_the_actions_that_reach_it(mask: LidarSafetyMask) -> None:
    clear = mask.allowed(th.as_tensor(wall_ahead(1, 1.0)))[0]  # 1.0 = the view's cap: nothing seen
    assert bool(clear.all())
    near = th.as_tensor(wall_ahead(1, ROBOT_RADIUS + 0.06))  # 6 cm past the body
    clearance, allowed = mask.clearance(near)[0], mask.allowed(near)[0]
    assert clearance[STAND_STILL] > MARGIN > clearance[FULL_AHEAD]
    assert not allowed[FULL_AHEAD] and allowed[STAND_STILL]
    assert th.equal(allowed, clearance > MARGIN)
    # Nothing safe (the wall inside the margin all round): the action that keeps the most clearance, alone.
    boxed = th.full((1, N_BEAMS + 2), ROBOT_RADIUS / 1.0 + 0.01)
    allowed = mask.allowed(boxed)[0]
    assert int(allowed.sum()) == 1 and int(allowed.int().argmax()) == int(mask.clearance(boxed)[0].argmax())


def test_exploration_draws_only_allowed_actions_and_all_of_them() -> None:
    rng = np.random.default_rng(0)
    allowed = np.zeros((4000, N_ACTIONS), dtype=bool)
    allowed[:, [0, 2, 7]] = True
    allowed[::2, 19] = True
    actions, explore = epsilon_greedy(np.full(4000, FULL_AHEAD), 1.0, N_ACTIONS, rng=rng, allowed=allowed)
    assert explore.all() and allowed[np.arange(4000), actions].all()
    counts = np.bincount(actions[1::2], minlength=N_ACTIONS)  # rows with three allowed actions: about a third each
    assert set(np.flatnonzero(counts)) == {0, 2, 7} and counts[[0, 2, 7]].min() > 600


def always_ahead(model: GDQ) -> None:
    """Make the model's networks rank full speed ahead first (by a wide advantage) and standing still last."""
    with th.no_grad():
        for net in {model.policy.q_net, model.policy.q_net_target, model.policy.greedy_net()}:
            last = net.advantage_stream[-1]
            last.weight.zero_()
            last.bias.zero_()
            last.bias[FULL_AHEAD] = 5.0
            last.bias[STAND_STILL] = -5.0


def test_a_masked_model_never_plays_explores_or_bootstraps_an_unsafe_action(tmp_path: Path) -> None:
    venv = make_vec_env("MultiRobotNav-4-v0", n_envs=1, seed=0, env_kwargs=SHORT_VIEW)
    kwargs = {"safety_margin": MARGIN}
    model = GDQ("MlpPolicy", venv, policy_kwargs=kwargs, learning_starts=0, seed=0)
    assert kwargs == {"safety_margin": MARGIN}  # the caller's dict is not filled in
    always_ahead(model)
    near, far = wall_ahead(8, ROBOT_RADIUS + 0.06), wall_ahead(8, 1.0)
    assert (model.predict(far, deterministic=True)[0] == FULL_AHEAD).all()
    played = model.predict(near, deterministic=True)[0]
    clearance = model.policy.safety_mask.clearance(th.as_tensor(near)).numpy()
    assert (played != FULL_AHEAD).all() and (clearance[np.arange(8), played] > MARGIN).all()
    model.exploration_rate = 1.0
    explored = np.concatenate([model.predict(near)[0] for _ in range(50)])
    assert (clearance[0, explored] > MARGIN).all() and len(np.unique(explored)) > 5
    # The double-Q target's next action: the best allowed one. Every action scores 0 but full speed ahead (+5) and
    # standing still (-5), so the target's advantage term is 0 with the mask and 5 without it.
    unmasked = GDQ("MlpPolicy", venv, learning_starts=0, seed=0)
    for each, expected in ((model, 0.0), (unmasked, 5.0)):
        each.learn(64)  # fills the buffer (and trains: the networks are set again after)
        always_ahead(each)
        samples = each.replay_buffer.sample(4)
        next_obs = th.as_tensor(wall_ahead(4 * 4, ROBOT_RADIUS + 0.06)).view(4, 4, -1)
        terms = each._td_terms(samples._replace(next_observations=next_obs))
        np.testing.assert_allclose(terms.next_advantage_term.numpy(), expected, atol=1e-5)
    # Saved and loaded without an env: the margin and the geometry come back, and so do the choices.
    model.save(tmp_path / "masked.zip")
    loaded = GDQ.load(tmp_path / "masked.zip")
    assert loaded.policy.safety_margin == MARGIN and loaded.policy.safety_geometry == model.policy.safety_geometry
    np.testing.assert_array_equal(loaded.predict(near, deterministic=True)[0], played)
    venv.close()


class _RecordingBlock(EvaluationBlock):
    """Keeps the actions it plays and the observations it played them on."""

    def start_recording(self, obs: np.ndarray, active: np.ndarray) -> None:
        self.played: list[tuple[np.ndarray, int]] = []
        self._obs = obs.copy()

    def record_step(self, index: int, action: int, next_obs: np.ndarray) -> None:
        self.played.append((self._obs[index].copy(), int(action)))
        self._obs[index] = next_obs


def test_eps_mutants_act_through_the_models_mask() -> None:
    # Every individual ranks full speed ahead first. A margin no action clears leaves each step the mask's fallback
    # (the most clearing action), found here from the observations the mutants saw; without a mask: always ahead.
    venv = make_vec_env("MultiRobotNav-4-v0", n_envs=1, seed=0, env_kwargs=SHORT_VIEW)
    model = GDQ("MlpPolicy", venv, seed=0)
    always_ahead(model)
    population = {
        name: param.detach()[None].repeat(2, *[1] * param.dim()) for name, param in model.policy.q_net.named_parameters()
    }
    for margin in (None, 5.0):
        short = {**SHORT_VIEW, "max_episode_steps": 48}  # 12 decisions
        block = _RecordingBlock("SingleRobotNav-v0", short, 2, 1, model.policy.q_net, safety_margin=margin)
        block.evaluate(population, [7], np.ones(2, dtype=bool))
        obs = th.as_tensor(np.stack([o for o, _ in block.played]))
        actions = np.array([a for _, a in block.played])
        if margin is None:
            assert (actions == FULL_AHEAD).all()
        else:
            fallback = block.safety_mask.clearance(obs).argmax(dim=1).numpy()
            np.testing.assert_array_equal(actions, fallback)
            assert (actions != FULL_AHEAD).any()
        block.close()
    venv.close()


def test_evolution_trains_a_masked_model_and_checks_its_eps_world() -> None:
    from sb3_eps import EvolutionCallback

    venv = make_vec_env("MultiRobotNav-4-v0", n_envs=1, seed=0, env_kwargs=SHORT_VIEW)
    model = GDQ("MlpPolicy", venv, policy_kwargs={"safety_margin": MARGIN}, learning_starts=0, seed=0)
    callback = EvolutionCallback(period=40, n_workers=0, max_eps_share=None, population_size=1, n_eval_episodes=1,
                                 n_reevaluation_episodes=0)  # fmt: skip
    model.learn(4 * 80, callback=callback)
    assert callback.n_rounds >= 1
    # An EPS world whose view differs from the mask's: one line naming what differs.
    other = EvolutionCallback(eval_env_id="SingleRobotNav-v0", eval_env_kwargs={"lidar_range": 3.5})
    with pytest.raises(ValueError, match=r"lidar_range=3.5 but the model's worlds have lidar_range=1.0"):
        model.learn(8, callback=other)
    # A model whose mask was built for another robot (here: a wider body) against this EPS world: one line.
    model.policy.safety_geometry = {**model.policy.safety_geometry, "robot_radius_m": ROBOT_RADIUS + 0.05}
    with pytest.raises(ValueError, match=r"geometry of eval_env_id 'SingleRobotNav-v0' differs .* in robot_radius_m"):
        model.learn(8, callback=EvolutionCallback(n_workers=0))
    venv.close()


def test_a_world_without_a_lidar_gets_a_one_line_error() -> None:
    venv = make_vec_env("CooperativeNavigation-v0", n_envs=1, seed=0)
    with pytest.raises(ValueError, match=r"safety_margin needs a world that describes its lidar.*remove policy_kwargs"):
        IQL("MlpPolicy", venv, policy_kwargs={"safety_margin": MARGIN})
    venv.close()


def test_the_exported_policy_applies_its_mask(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from sb3_eps import export_policy
    from sb3_eps.deploy import OnnxPolicy

    venv = make_vec_env("MultiRobotNav-4-v0", n_envs=1, seed=0, env_kwargs=SHORT_VIEW)
    model = GDQ("MlpPolicy", venv, policy_kwargs={"safety_margin": MARGIN}, seed=0)
    always_ahead(model)
    _, json_path = export_policy(model, tmp_path / "masked")
    assert json.loads(Path(json_path).read_text())["safety_margin"] == MARGIN
    policy = OnnxPolicy.load(json_path, threads=1)
    near = wall_ahead(6, ROBOT_RADIUS + 0.06)
    np.testing.assert_array_equal(policy.act(near), model.predict(near, deterministic=True)[0])
    assert (policy.act(near, safety_margin=None) == FULL_AHEAD).all()  # the network alone
    with pytest.raises(ValueError, match="'trained'"):
        policy.act(near, safety_margin="yes")
    venv.close()
