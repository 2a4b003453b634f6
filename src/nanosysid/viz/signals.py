"""Signals as people read them: h-step-ahead predictions along a flight, attitude as Euler
angles, one colour per model. Shared by the report's figures and the rerun recordings."""

from __future__ import annotations

import numpy as np
import torch

from nanosysid import so3

__all__ = ["ahead", "euler_deg", "readable", "model_color", "SIGNALS"]

# name, unit, axis labels of the four quantities as drawn (attitude as roll, pitch, yaw)
SIGNALS = {
    "p": ("position", "m", ("x", "y", "z")),
    "v": ("velocity", "m/s", ("vx", "vy", "vz")),
    "R": ("attitude", "deg", ("roll", "pitch", "yaw")),
    "w": ("angular velocity", "rad/s", ("wx", "wy", "wz")),
}

_COLORS = {"truth": "#222222", "naive": "#e377c2", "physics": "#1f77b4", "physics_full": "#8c564b",
           "residual": "#2ca02c", "phys_res": "#ff7f0e", "lstm": "#9467bd", "oracle": "#7f7f7f"}
_CYCLE = ["#17becf", "#bcbd22", "#d62728", "#393b79", "#637939", "#8c6d31"]


def model_color(name: str, index: int = 0) -> str:
    """A fixed colour per known model (the paper's pink for naive), a cycle for the others."""
    return _COLORS.get(name, _CYCLE[index % len(_CYCLE)])


def ahead(rollouts: np.ndarray, h: int, n_samples: int, starts: np.ndarray | None = None) -> np.ndarray:
    """The ``h``-step-ahead prediction along a flight, ``(T, 13)``.

    ``rollouts (N, H, 13)`` are the predictions from the samples ``starts`` (every start
    ``0..N-1`` by default; see :func:`nanosysid.protocol.predictions`); row ``t`` of the
    result is ``ŷ_{t|t-h}``, and NaN where no rollout predicts sample ``t`` from ``h`` steps before.
    """
    starts = np.arange(len(rollouts)) if starts is None else np.asarray(starts)
    out = np.full((n_samples, rollouts.shape[-1]), np.nan)
    out[starts + h] = rollouts[:, h - 1]
    return out


def euler_deg(q: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (ZYX convention, degrees) of quaternions ``(..., 4)`` (xyzw); NaN
    rows stay NaN. Yaw is unwrapped along the first axis so a turn draws as a line."""
    R = so3.quat_to_rotmat(torch.from_numpy(np.ascontiguousarray(q, dtype=np.float64))).numpy()
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    ok = np.isfinite(yaw)
    if yaw.ndim == 1 and ok.any():
        yaw[ok] = np.unwrap(yaw[ok])
    return np.degrees(np.stack([roll, pitch, yaw], axis=-1))


def readable(y: np.ndarray) -> dict[str, np.ndarray]:
    """Outputs ``(..., 13)`` as the four quantities of :data:`SIGNALS`, three columns each."""
    return {"p": y[..., 0:3], "v": y[..., 3:6], "R": euler_deg(y[..., 6:10]), "w": y[..., 10:13]}
