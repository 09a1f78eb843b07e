"""Looking inside one EPS round: per-layer summaries of the sensitivity (Eq. 6) and of mutation steps, the effect of
the noise scale on the greedy policy, and figures of a population's evaluation.

These are the notebook's view of :mod:`sb3_eps.eps.mutations` (``notebooks/02_inside_eps.ipynb``); the callback
does not use them. Figures are made without pyplot (``display(figure)`` shows one in a notebook).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th
from matplotlib.figure import Figure
from torch import nn

from sb3_eps.eps.evaluation import OUTCOMES, PopulationResult
from sb3_eps.eps.mutations import Parameters, policy_change, population_from_directions, population_outputs


def sensitivity_by_layer(sensitivity: Parameters, floor: float = 0.01) -> list[dict[str, Any]]:
    """Summarise Eq. 6's sensitivity ``omega`` per parameter tensor.

    :param sensitivity: ``omega`` (:func:`~sb3_eps.eps.mutations.output_sensitivity`)
    :param floor: the safe mutation's lower bound on ``omega`` (``EvolutionCallback.sensitivity_floor``)
    :return: one row per parameter: ``layer``, ``n_weights``, ``mean``, ``median``, ``max`` of ``omega``, and
        ``at_floor``: the share of weights whose step is set by the floor (``omega < floor``; 0 counts as 1,
        as :func:`~sb3_eps.eps.mutations.safe_mutation_step` treats it)
    """
    rows = []
    for name, omega in sensitivity.items():
        values = omega.detach().reshape(-1).double().cpu()
        effective = th.where(values == 0, th.ones_like(values), values)
        rows.append(
            {
                "layer": name,
                "n_weights": int(values.numel()),
                "mean": float(values.mean()),
                "median": float(values.median()),
                "max": float(values.max()),
                "at_floor": float((effective < floor).double().mean()),
            }
        )
    return rows


def step_by_layer(directions: Parameters, scale: float, max_step: float = float("inf")) -> list[dict[str, Any]]:
    """Summarise the mutation steps ``clip(scale * direction, -max_step, max_step)`` per parameter tensor.

    :param directions: ``{name: (m, *shape)}`` (:func:`~sb3_eps.eps.mutations.mutation_directions`)
    :param scale: the noise scale
    :param max_step: the per-weight clip
    :return: one row per mutated parameter: ``layer``, ``mean_abs_step``, ``max_abs_step``, ``clipped`` (share)
    """
    rows = []
    for name, direction in directions.items():
        raw = (scale * direction.detach()).abs().double().cpu()
        step = raw.clamp(max=max_step)
        rows.append(
            {
                "layer": name,
                "mean_abs_step": float(step.mean()),
                "max_abs_step": float(step.max()),
                "clipped": float((raw > max_step).double().mean()),
            }
        )
    return rows


def flip_share_curve(
    network: nn.Module,
    parameters: Parameters,
    directions: Parameters,
    observations: th.Tensor,
    scales: Sequence[float],
    max_step: float = float("inf"),
) -> np.ndarray:
    """The mean share of greedy actions the mutants change, at each noise scale (what the calibration searches).

    :param network: the agent network
    :param parameters: its weights ``theta``
    :param directions: unit-scale mutation steps
    :param observations: visited observations ``(B, obs_dim)``
    :param scales: the noise scales to try
    :param max_step: the per-weight clip
    :return: ``(len(scales),)`` shares in [0, 1]
    """
    shares = []
    for scale in scales:
        population = population_from_directions(parameters, directions, float(scale), max_step)
        flip_share, _ = policy_change(population_outputs(network, population, observations))
        shares.append(float(flip_share[1:].mean()))
    return np.array(shares)


def draw_layer_bars(tables: dict[str, list[dict[str, Any]]], key: str, title: str | None = None, log: bool = True) -> Figure:
    """Bars of one column of per-layer tables, side by side for each table (e.g. safe vs Gaussian steps).

    :param tables: ``{label: rows}`` from :func:`sensitivity_by_layer` or :func:`step_by_layer`
    :param key: the column to draw
    :param title: the axis title
    :param log: logarithmic y axis
    :return: the figure
    """
    layers = list(dict.fromkeys(row["layer"] for rows in tables.values() for row in rows))
    figure = Figure(figsize=(max(6.0, 0.7 * len(layers) * max(len(tables), 1)), 3.6))
    axis = figure.subplots()
    width = 0.8 / max(len(tables), 1)
    for index, (label, rows) in enumerate(tables.items()):
        by_layer = {row["layer"]: row[key] for row in rows}
        positions = np.arange(len(layers)) + (index - (len(tables) - 1) / 2) * width
        axis.bar(positions, [by_layer.get(layer, np.nan) for layer in layers], width, label=label)
    axis.set_xticks(np.arange(len(layers)), layers, rotation=45, ha="right", fontsize="small")
    axis.set_ylabel(key)
    if log:
        axis.set_yscale("log")
    if title:
        axis.set_title(title)
    if len(tables) > 1:
        axis.legend(fontsize="small")
    axis.grid(alpha=0.3, axis="y")
    figure.tight_layout()
    return figure


def draw_flip_curves(scales: Sequence[float], curves: dict[str, np.ndarray], target: float | None = None) -> Figure:
    """Share of greedy actions changed against the noise scale, one line per mutation operator.

    :param scales: the noise scales
    :param curves: ``{label: shares}`` (:func:`flip_share_curve`)
    :param target: the calibration's target share, drawn as a dotted line
    :return: the figure
    """
    figure = Figure(figsize=(6, 3.6))
    axis = figure.subplots()
    for label, shares in curves.items():
        axis.plot(scales, 100 * np.asarray(shares), marker="o", label=label)
    if target is not None:
        axis.axhline(100 * target, color="grey", linestyle=":", label=f"target {100 * target:.0f} %")
    axis.set_xscale("log")
    axis.set_xlabel("noise scale sigma")
    axis.set_ylabel("greedy actions changed (%)")
    axis.grid(alpha=0.3)
    axis.legend(fontsize="small")
    figure.tight_layout()
    return figure


def draw_population(result: PopulationResult, flip_share: np.ndarray | None = None, winner: int | None = None) -> Figure:
    """One evaluation round: every individual's episodes, its fitness, and how far it moved the greedy policy.

    :param result: :func:`~sb3_eps.eps.evaluation.evaluate_population`'s result (individual 0 = unmutated copy)
    :param flip_share: ``(P,)`` share of greedy actions changed (:func:`~sb3_eps.eps.mutations.policy_change`)
    :param winner: the selected individual, outlined in red
    :return: the figure: episode returns (reached targets marked), fitness, and optionally the flip share
    """
    n_panels = 3 if flip_share is not None else 2
    figure = Figure(figsize=(4.2 * n_panels, 3.6))
    axes = figure.subplots(1, n_panels)
    n_individuals, n_episodes = result.returns.shape
    image = axes[0].imshow(result.returns, aspect="auto", cmap="RdYlGn")
    figure.colorbar(image, ax=axes[0], label="episode return")
    outcomes = result.outcomes if result.outcomes is not None else np.zeros_like(result.lengths)
    marks = {OUTCOMES["success"]: "*", OUTCOMES["failure"]: "x"}
    for (individual, episode), outcome in np.ndenumerate(outcomes):
        if int(outcome) in marks:
            axes[0].text(episode, individual, marks[int(outcome)], ha="center", va="center", color="black")
    axes[0].set_xlabel("episode (same seeds for everyone)")
    axes[0].set_ylabel("individual (0 = unmutated)")
    axes[0].set_title("returns (* reached, x crashed)")
    axes[0].set_yticks(range(n_individuals))
    axes[0].set_xticks(range(n_episodes))
    colors = ["C3" if index == winner else "C0" for index in range(n_individuals)]
    fitness = np.where(np.isfinite(result.fitness), result.fitness, np.nan)
    axes[1].bar(range(n_individuals), fitness, color=colors)
    axes[1].set_xlabel("individual")
    axes[1].set_ylabel("fitness (Eq. 4)")
    axes[1].set_title("fitness" + (f" (winner {winner} in red)" if winner is not None else ""))
    if flip_share is not None:
        axes[2].bar(range(n_individuals), 100 * np.asarray(flip_share), color=colors)
        axes[2].set_xlabel("individual")
        axes[2].set_ylabel("greedy actions changed (%)")
        axes[2].set_title("policy change vs individual 0")
    for axis in axes[1:]:
        axis.set_xticks(range(n_individuals))
        axis.grid(alpha=0.3, axis="y")
    figure.tight_layout()
    return figure


def team_check_changes(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The paired greedy team checks of the rounds that crossed over (``n_team_check_episodes > 0``).

    Each check plays the same episodes (one seed) before and after the crossover, so the change is the crossover's
    effect on the multi-robot policy, apart from the ticks EPS takes from training.

    :param records: the records of an ``eps_rounds.jsonl`` file (or ``EvolutionCallback.history``)
    :return: one dict per checked crossover: ``round``, ``model_ticks``, ``alpha``, ``gain``, the success and the team
        return before and after, and their changes ``success_change`` and ``return_change``
    """
    changes = []
    for record in records:
        if record.get("skipped") or "team_success_after" not in record:
            continue
        before, after = record["team_success_before"], record["team_success_after"]
        changes.append(
            {
                "round": record["round"],
                "model_ticks": record["model_ticks"],
                "alpha": record["alpha"],
                "gain": record["gain"],
                "success_before": before,
                "success_after": after,
                "success_change": after - before,
                "return_change": record["team_return_after"] - record["team_return_before"],
            }
        )
    return changes
