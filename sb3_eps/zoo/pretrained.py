"""Trained teams shipped with the package (``sb3_eps/trained_agents/``), as RL Zoo ships ``rl-trained-agents``.

Each model is a run folder of ``python -m sb3_eps.train`` cut down to what predicting needs (``args.yml``,
``config.yml``, the final ``<env id>.zip``) plus its model card: ``card.json`` (how it was trained, the world options
it needs, its figures on 100 greedy team episodes per world it is shipped for, the zip's SHA-256) and ``README.md``
(the same card for people). A model serves every env id its card lists in ``serves``: the 4-robot model is also the
unseen room's.

    model = sb3_eps.pretrained("gdq", "MultiRobotNav-12-v0")
    card = sb3_eps.model_card("gdq", "MultiRobotNav-12-v0")
    venv = sb3_eps.make_vec_env("MultiRobotNav-12-v0", n_envs=4, env_kwargs=card.env_kwargs)
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_eps.zoo.errors import ConfigError
from sb3_eps.zoo.evaluation import LoadedRun, load_run

#: Where the shipped models live (package data).
TRAINED_AGENTS = Path(__file__).resolve().parents[1] / "trained_agents"
CARD_NAME = "card.json"
CARD_PAGE_NAME = "README.md"


@dataclass
class ModelCard:
    """What a shipped model is: ``card.json`` of its folder.

    :param algo: the algorithm (``--algo``)
    :param env_id: the env id it trained on
    :param serves: the env ids :func:`pretrained` gives it for (its training world first)
    :param env_kwargs: the world options it was trained with and needs everywhere (a model that sees 1 m of lidar
        must be given worlds that show it 1 m)
    :param seed: the training seed
    :param command: the command that trained it
    :param code_version: the package version and commit it was trained with
    :param training_ticks: world ticks of training (all worlds together)
    :param wall_time_s: the training's wall time and the machine (``machine``)
    :param sha256: the SHA-256 of the model zip, checked on every load
    :param figures: env id -> the greedy evaluation it was measured with (``success_rate``, ``collision_rate``,
        ``team_return_mean``, ``n_episodes``, ``seed``, ``env_kwargs``)
    :param notes: where the setting comes from
    :param folder: the model's folder
    """

    algo: str
    env_id: str
    serves: list[str]
    env_kwargs: dict[str, Any]
    seed: int
    command: str
    code_version: str
    training_ticks: int
    wall_time_s: float
    machine: str
    sha256: str
    figures: dict[str, dict[str, Any]] = field(default_factory=dict)
    notes: str = ""
    folder: Path = field(default=Path("."), compare=False)

    @property
    def model_path(self) -> Path:
        """The model zip (RL Zoo's final-model name, ``<env id>.zip``)."""
        return self.folder / f"{self.env_id}.zip"

    def to_json(self) -> str:
        """:return: ``card.json``'s text (without the folder)."""
        record = {key: value for key, value in vars(self).items() if key != "folder"}
        return json.dumps(record, indent=2) + "\n"

    @classmethod
    def read(cls, folder: Path) -> ModelCard:
        """:return: the card of a model folder. :raises ConfigError: when ``card.json`` is missing or malformed"""
        path = folder / CARD_NAME
        try:
            record = json.loads(path.read_text())
            return cls(**record, folder=folder)
        except (OSError, ValueError, TypeError) as error:
            raise ConfigError(f"{path}: not a model card ({error})") from None


def cards(root: Path = TRAINED_AGENTS) -> list[ModelCard]:
    """:return: the card of every shipped model, in the order of their folders."""
    return [ModelCard.read(path.parent) for path in sorted(root.glob(f"*/*/{CARD_NAME}"))]


def available(root: Path = TRAINED_AGENTS) -> dict[tuple[str, str], ModelCard]:
    """:return: (algo, env id) -> the card of the shipped model for it, for every env id a card serves."""
    found: dict[tuple[str, str], ModelCard] = {}
    for card in cards(root):
        for env_id in card.serves:
            found.setdefault((card.algo, env_id), card)
    return found


def model_card(algo: str, env_id: str, root: Path = TRAINED_AGENTS) -> ModelCard:
    """:return: the card of the shipped model for ``algo`` on ``env_id``.

    :raises ConfigError: when none is shipped, listing what is
    """
    cards = available(root)
    card = cards.get((algo, env_id))
    if card is None:
        shipped = ", ".join(f"{a} {e}" for a, e in sorted(cards)) or "none"
        raise ConfigError(f"no pretrained {algo} model for {env_id}; shipped: {shipped}")
    return card


def sha256_of(path: Path) -> str:
    """:return: the file's SHA-256 as hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def pretrained_run(algo: str, env_id: str, device: str = "auto", root: Path = TRAINED_AGENTS) -> LoadedRun:
    """Load a shipped model as a run (its world options with it), for evaluation and ``enjoy``.

    :raises ConfigError: when none is shipped or the zip is not the one its card names (SHA-256)
    """
    card = model_card(algo, env_id, root)
    if not card.model_path.is_file():
        raise ConfigError(f"{card.model_path} is missing: reinstall sb3-eps")
    if sha256_of(card.model_path) != card.sha256:
        raise ConfigError(f"{card.model_path} differs from its model card (SHA-256): reinstall sb3-eps")
    return load_run(card.folder, "final", device)  # with its world options, from its config.yml as the card's


def load_pretrained(algo: str, env_id: str, device: str = "auto") -> Any:
    """:return: the shipped ``algo`` model for ``env_id``, without an env (its card says which world options it
    needs: :func:`model_card`)."""
    return pretrained_run(algo, env_id, device).model
