"""When an EPS round may start: ``period`` units after the previous one, and only while the EPS ticks stay within
``max_eps_share`` of the training ticks (the tick budget; evidence in ``docs/results/eps.md``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_eps.eps.settings import EPSSettings


def model_ticks(model: Any) -> int:
    """:return: the world ticks the model has trained on (``model.ticks``; SB3's timesteps for a one-agent model)."""
    return int(getattr(model, "ticks", model.num_timesteps))


class RoundBudget:
    """The period and the tick budget of the rounds.

    :param settings: the EPS settings (``period``, ``period_unit``, ``max_eps_share`` and the episode counts)
    """

    def __init__(self, settings: EPSSettings) -> None:
        self.settings = settings
        self.last_round_mark: int | None = None
        """The progress (ticks or episodes, :meth:`progress`) at the previous round, or at the start."""
        self.episode_limit = 0
        """The evaluation world's time limit, for the first round's cost estimate."""

    def progress(self, model: Any) -> int:
        """:return: the training's progress in ``period_unit``."""
        if self.settings.period_unit == "episodes":
            return int(model._episode_num)
        return model_ticks(model)

    def start(self, model: Any) -> None:
        """Start counting the period; a ``learn()`` that continues the count (``reset_num_timesteps=False``) keeps
        the period running."""
        if self.last_round_mark is None or self.progress(model) < self.last_round_mark:
            self.last_round_mark = self.progress(model)

    def due(self, model: Any) -> bool:
        """:return: whether ``period`` units have passed since the previous round (and ``rounds_until`` has not)."""
        assert self.last_round_mark is not None
        until = self.settings.rounds_until
        if until is not None and model_ticks(model) > until:
            return False
        return self.progress(model) - self.last_round_mark >= self.settings.period

    def mark(self, model: Any) -> None:
        """A round starts now."""
        self.last_round_mark = self.progress(model)

    def within(self, eps_ticks: int, training_ticks: int, history: list[dict[str, Any]]) -> bool:
        """:return: whether a round now keeps the EPS ticks within ``max_eps_share`` of the training ticks, if it
        plays every episode it may (the reevaluation too) at the previous round's mean episode length."""
        if self.settings.max_eps_share is None:
            return True
        return eps_ticks + self.expected_round_cost(history) <= self.settings.max_eps_share * training_ticks

    def expected_round_cost(self, history: list[dict[str, Any]]) -> float:
        """:return: the ticks a round is expected to cost: every episode it may play at the last round's mean
        episode length, or before the first round half of the most it can cost."""
        n_played = self.settings.most_episodes_per_round
        # The last round's episodes stand for the policy now (earlier rounds' mean underestimated, docs/results/eps.md).
        done = [record for record in history if not record.get("skipped")]
        last = done[-1] if done else {}
        played = np.concatenate(
            [
                np.ravel(last.get("episode_lengths", [])),
                np.ravel(last.get("reevaluation", {}).get("episode_lengths", [])),
            ]
        ).astype(float)
        played = played[played > 0]  # disqualified individuals' unplayed episodes
        if not played.size:
            return 0.5 * n_played * self.episode_limit
        return float(played.mean()) * n_played

    def why_no_round(self, eps_ticks: int, start_ticks: int, end_ticks: int, history: list[dict[str, Any]]) -> str | None:
        """:return: why no round can play between ``start_ticks`` and ``end_ticks`` training ticks (None when one
        can): the tick budget never covers a round's expected cost, or a period in ticks is longer than the run."""
        settings = self.settings
        if settings.rounds_until is not None and start_ticks >= settings.rounds_until:
            return f"rounds_until={settings.rounds_until} ticks is not after this run's start ({start_ticks} ticks)"
        if settings.period_unit == "ticks" and self.last_round_mark is not None:
            if end_ticks - self.last_round_mark < settings.period:
                return (
                    f"period={settings.period} ticks is longer than this run's {end_ticks - start_ticks} training "
                    "ticks: lower period or train longer"
                )
        if settings.max_eps_share is None:
            return None
        cost = self.expected_round_cost(history)
        if eps_ticks + cost > settings.max_eps_share * end_ticks:
            return (
                f"a round is expected to cost {cost:.0f} ticks, more than max_eps_share={settings.max_eps_share} of "
                f"the {end_ticks} training ticks this run ends at allows: raise max_eps_share (None: no budget), "
                "lower n_eval_episodes / n_reevaluation_episodes, or train longer"
            )
        return None
