"""Multi-step prediction: a generic rollout over any one-step map, and the predictor wrapper.

A *step map* is ``step(y (B, 13), u (B, 4)) -> y_next (B, 13)``. A *predictor*, the object
the benchmark calls, is ``predict(y0 (B, 13), u (B, H, 4)) -> (B, H, 13)``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from torch import Tensor

from nanosysid.numerics import LOOP_THREADS, threads

__all__ = ["rollout", "StepPredictor", "as_tensor", "advance_inputs"]

StepFn = Callable[[Tensor, Tensor], Tensor]


@threads(LOOP_THREADS)
def rollout(step: StepFn, y0: Tensor, u: Tensor) -> Tensor:
    """Open-loop rollout: ``y_{h} = step(y_{h-1}, u_{h-1})`` for h = 1..H, no correction.

    Runs on :data:`~nanosysid.numerics.LOOP_THREADS` of torch's threads (a loop over time on
    small tensors: more threads wait on each other, and on any other busy process, at each step).

    Args:
        step: One-step map.
        y0: Initial outputs ``(B, 13)``.
        u: Inputs ``(B, H, 4)``; ``u[:, h]`` drives the step from h to h + 1.

    Returns:
        Predictions ``(B, H, 13)`` for h = 1..H.
    """
    ys = []
    y = y0
    for h in range(u.shape[1]):  # the only loop over time, inside the rollout
        y = step(y, u[:, h])
        ys.append(y)
    return torch.stack(ys, dim=1)


def advance_inputs(u: Tensor, shift: float) -> Tensor:
    """Inputs ``(B, H, m)`` read ``shift`` samples later along the horizon: the value at
    ``h + shift``, linearly interpolated, the last sample held beyond the window. Undoes a
    delay of ``shift`` samples in recorded inputs."""
    if shift == 0:
        return u
    H = u.shape[1]
    pos = torch.clamp(torch.arange(H, dtype=u.dtype) + shift, min=0, max=H - 1)
    lo = pos.floor().long()
    hi = torch.clamp(lo + 1, max=H - 1)
    w = (pos - lo).view(1, H, 1)
    return u[:, lo] * (1 - w) + u[:, hi] * w


def as_tensor(a, dtype: torch.dtype) -> Tensor:
    """A tensor of ``dtype`` from a numpy array or tensor, without copying when possible."""
    if isinstance(a, Tensor):
        return a.to(dtype)
    a = np.ascontiguousarray(a)
    if not a.flags.writeable:  # the benchmark hands predictors read-only views; torch needs its own
        return torch.tensor(a, dtype=dtype)
    return torch.from_numpy(a).to(dtype)


class StepPredictor:
    """Wrap a step map as a benchmark predictor (numpy or torch in, numpy out).

    Args:
        step: One-step map (an ``nn.Module`` or a function).
        dtype: Precision of the rollout.
        name: Label used in reports.
    """

    def __init__(self, step: StepFn, *, dtype: torch.dtype = torch.float64, name: str = "") -> None:
        self.step = step
        self.dtype = dtype
        self.name = name

    @torch.no_grad()
    def __call__(self, y0, u) -> np.ndarray:
        y0_t = as_tensor(y0, self.dtype)
        u_t = as_tensor(u, self.dtype)
        return rollout(self.step, y0_t, u_t).numpy()

    def __repr__(self) -> str:
        return f"StepPredictor({self.name or self.step!r})"
