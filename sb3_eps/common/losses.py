"""Loss reductions shared by the algorithms (masked over agents, weighted by PER importance weights)."""

from __future__ import annotations

import torch as th
import torch.nn.functional as F


def masked_huber(prediction: th.Tensor, target: th.Tensor, mask: th.Tensor, weights: th.Tensor) -> th.Tensor:
    """Huber loss of per-agent predictions averaged over the real (``mask`` = 1) transitions.

    :param prediction: ``(B, n)``
    :param target: ``(B, n)``, no gradient
    :param mask: ``(B, n)`` 1 where the agent's transition is real
    :param weights: ``(B,)`` importance-sampling weights of the rows
    """
    if not (prediction.shape == target.shape == mask.shape) or weights.shape != prediction.shape[:1]:
        raise ValueError(
            f"masked_huber shapes: prediction {tuple(prediction.shape)}, target {tuple(target.shape)}, "
            f"mask {tuple(mask.shape)}, weights {tuple(weights.shape)}"
        )
    per_agent = F.smooth_l1_loss(prediction, target, reduction="none")
    return (per_agent * mask * weights[:, None]).sum() / mask.sum().clamp(min=1.0)


def weighted_huber(prediction: th.Tensor, target: th.Tensor, weights: th.Tensor) -> th.Tensor:
    """Huber loss of per-row predictions ``(B,)`` weighted by the importance weights ``(B,)``."""
    if not (prediction.shape == target.shape == weights.shape):
        raise ValueError(f"weighted_huber shapes: {tuple(prediction.shape)}, {tuple(target.shape)}, {tuple(weights.shape)}")
    return (F.smooth_l1_loss(prediction, target, reduction="none") * weights).mean()


def row_priority(errors: th.Tensor, mask: th.Tensor) -> th.Tensor:
    """Largest absolute TD error among a row's real transitions, ``(B, n) -> (B,)``."""
    return (errors.detach().abs() * mask).max(dim=1).values
