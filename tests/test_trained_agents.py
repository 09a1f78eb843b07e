"""The shipped trained models (``sb3_eps/trained_agents/``): each still plays as its card says, loads in one line,
refuses a changed file, and ``python -m sb3_eps.enjoy`` watches one without training."""

from __future__ import annotations

import shutil
from pathlib import Path

import imageio.v2 as imageio
import pytest

import envs  # noqa: F401
import sb3_eps
from sb3_eps import enjoy
from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.evaluation import evaluate_run
from sb3_eps.zoo.pretrained import TRAINED_AGENTS, available, cards, model_card, pretrained_run

ROOT = Path(__file__).resolve().parents[1]
CARDS = cards(TRAINED_AGENTS)
#: Episodes per model in the regression check, the points a model may fall below its card's 100-episode figure, and
#: the evaluation seed (neither the card's nor the reproduction's).
EPISODES, ALLOWED_FALL, SEED = 20, 10.0, 3000
#: Where success is not reached at all (MPE), the team return may fall this much below the card's.
ALLOWED_RETURN_FALL = 10.0


def test_a_model_is_shipped_for_each_world_family() -> None:
    shipped = set(available())
    for env_id in ("MultiRobotNav-4-v0", "MultiRobotNav-8-v0", "MultiRobotNav-12-v0", "MultiRobotNavUnseen-4-v0",
                   "CooperativeNavigation-v0", "MultiRobotNavRooms-8-test-v0"):  # fmt: skip
        assert ("gdq", env_id) in shipped, f"no shipped model for {env_id}"
    for card in CARDS:
        assert card.figures.keys() == set(card.serves), f"{card.folder}: a served world has no figure"
        assert all(figure["n_episodes"] >= 100 for figure in card.figures.values())
        assert card.model_path.stat().st_size < 2_000_000


@pytest.mark.parametrize("card", CARDS, ids=[f"{card.algo}-{card.env_id}" for card in CARDS])
def test_a_shipped_model_plays_as_its_card_says(card) -> None:
    """20 greedy team episodes on another evaluation seed, in the world it trained in, no more than 10 points below
    the card's 100 episodes (and within 10 of its team return where nobody succeeds)."""
    figure = card.figures[card.env_id]
    summary = evaluate_run(pretrained_run(card.algo, card.env_id), card.env_id, EPISODES, n_envs=4, seed=SEED)
    assert summary["env_kwargs"] == card.env_kwargs
    if figure["success_rate"] > 0:
        assert 100 * summary["success_rate"] >= 100 * figure["success_rate"] - ALLOWED_FALL
    else:
        assert summary["team_return_mean"] >= figure["team_return_mean"] - ALLOWED_RETURN_FALL


def test_pretrained_loads_in_one_line_and_predicts_in_its_world() -> None:
    model = sb3_eps.pretrained("gdq", "MultiRobotNav-4-v0", device="cpu")
    card = sb3_eps.model_card("gdq", "MultiRobotNav-4-v0")
    venv = sb3_eps.make_vec_env("MultiRobotNav-4-v0", n_envs=1, seed=0, env_kwargs=card.env_kwargs)
    actions, _ = model.predict(venv.reset(), deterministic=True)
    assert actions.shape == (4,)
    venv.close()


def test_an_unknown_model_is_one_line_naming_what_is_shipped() -> None:
    with pytest.raises(ConfigError, match=r"no pretrained qmix model for MultiRobotNav-8-v0; shipped: gdq "):
        model_card("qmix", "MultiRobotNav-8-v0")


def test_a_changed_model_file_is_refused(tmp_path) -> None:
    card = model_card("gdq", "MultiRobotNav-4-v0")
    copy = tmp_path / card.algo / card.env_id
    shutil.copytree(card.folder, copy)
    with open(copy / card.model_path.name, "ab") as file:
        file.write(b"\0")
    with pytest.raises(ConfigError, match=r"differs from its model card \(SHA-256\)"):
        pretrained_run(card.algo, card.env_id, root=tmp_path)


def test_enjoy_watches_a_shipped_team_without_training_and_writes_a_gif(tmp_path, capsys) -> None:
    gif = tmp_path / "out.gif"
    assert enjoy.main(["--algo", "gdq", "--env", "MultiRobotNavUnseen-4-v0", "--no-render", "--gif", str(gif), "-n", "1"]) == 0
    out = capsys.readouterr().out
    assert "episode 1/1: " in out and "robots arrived" in out and "1 episodes: success" in out
    frames = imageio.mimread(gif)
    assert len(frames) > 10 and frames[0].shape[2] == 3


def test_enjoy_plays_a_run_folder_and_refuses_a_world_of_another_kind(tmp_path) -> None:
    folder = model_card("gdq", "MultiRobotNav-4-v0").folder
    assert enjoy.main(["--run", str(folder), "--env", "MultiRobotNav-2-v0", "--no-render", "-n", "1"]) == 0
    with pytest.raises(ConfigError, match=r"CooperativeNavigation-v0 does not take the world options .*action_repeat"):
        enjoy.main(["--run", str(folder), "--env", "CooperativeNavigation-v0", "--no-render", "-n", "1"])
    mpe = model_card("gdq", "CooperativeNavigation-v0").folder
    with pytest.raises(ConfigError, match=r"MultiRobotNav-4-v0 has observation_space"):
        enjoy.main(["--run", str(mpe), "--env", "MultiRobotNav-4-v0", "--no-render", "-n", "1"])
    with pytest.raises(ConfigError, match=r"-f: name the run's world with --env"):
        enjoy.main(["-f", str(tmp_path), "--no-render"])


def test_the_trained_teams_page_is_what_thecards_render() -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("trained_agents", ROOT / "research" / "trained_agents.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.PAGE.read_text() == module.results_page(), "re-render: python research/trained_agents.py page"


def test_the_ship_command_reaches_ship_with_the_training_command(monkeypatch, tmp_path) -> None:
    """``research/trained_agents.py ship`` passes its flags on (its ``--command`` must not shadow the sub-command)."""
    from research import trained_agents

    calls = []

    class Shipped:
        folder = tmp_path

    def fake_ship(run, commit, serves, notes, command):
        calls.append((run, commit, serves, notes, command))
        return Shipped()

    monkeypatch.setattr(trained_agents, "ship", fake_ship)
    argv = ["ship", "--run", str(tmp_path), "--commit", "abc1234", "--serves", "A-v0", "--command", "python -m x"]
    assert trained_agents.main(argv) == 0
    assert calls == [(tmp_path, "abc1234", ["A-v0"], "", "python -m x")]
