"""Multi-horizon error metrics of the benchmark protocol, vectorised over windows.

Arrays follow one layout: ``(N, H, 13)`` for N windows of H predicted steps, the last
axis in the output order ``[p, v, q (xyzw), w]``.
"""

from __future__ import annotations

import numpy as np
import torch

from nanosysid import so3

__all__ = ["QUANTITIES", "UNITS", "SLICES", "errors"]

QUANTITIES = ("p", "v", "R", "w")
UNITS = {"p": "m", "v": "m/s", "R": "rad", "w": "rad/s"}
SLICES = {"p": slice(0, 3), "v": slice(3, 6), "R": slice(6, 10), "w": slice(10, 13)}


def errors(y_true: np.ndarray, y_pred: np.ndarray) -> dict[str, np.ndarray]:
    """Per-window, per-horizon errors ``(N, H)`` for each quantity.

    Euclidean norm for position, velocity and angular velocity; geodesic angle on SO(3)
    for orientation (invariant to the scale and sign of either quaternion).
    """
    if y_true.shape != y_pred.shape or y_true.shape[-1] != 13:
        raise ValueError(f"shape mismatch: truth {y_true.shape}, prediction {y_pred.shape}")
    out = {k: np.linalg.norm(y_true[..., s] - y_pred[..., s], axis=-1) for k, s in SLICES.items() if k != "R"}
    q_t = torch.from_numpy(np.ascontiguousarray(y_true[..., 6:10], dtype=np.float64))
    q_p = torch.from_numpy(np.ascontiguousarray(y_pred[..., 6:10], dtype=np.float64))
    out["R"] = so3.geodesic_angle(q_t, q_p).numpy()
    return {k: out[k] for k in QUANTITIES}
