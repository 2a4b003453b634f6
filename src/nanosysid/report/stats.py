"""Trajectory statistics of flights, in the layout of the paper's table of trajectory statistics."""

from __future__ import annotations

import numpy as np
import torch

from nanosysid import so3
from nanosysid.dataio import Flight
from nanosysid.report.paper import PAPER_STATS

__all__ = ["flight_stats", "trajectory_stats", "stats_markdown", "STAT_NAMES", "STAT_LABELS"]

STAT_NAMES = ("duration", "v_mean", "v_max", "a_max", "tilt_max")
STAT_LABELS = {"duration": "Duration [s]", "v_mean": "v_mean [m/s]", "v_max": "v_max [m/s]",
               "a_max": "a_max [m/s²]", "tilt_max": "Max tilt [°]"}

def flight_stats(f: Flight, gravity: float = 9.81) -> dict[str, float]:
    """Duration, mean and max speed, max acceleration and max tilt of one flight.

    Speed is the norm of the velocity column; acceleration is the world-frame acceleration
    the accelerometer implies, ``R a_IMU - g``; tilt is the angle between body and world z.
    """
    q = torch.from_numpy(f.y[:, 6:10])
    speed = np.linalg.norm(f.y[:, 3:6], axis=1)
    a_imu = torch.from_numpy(np.column_stack([f.extra[c] for c in ("ax_body", "ay_body", "az_body")]))
    acc = so3.quat_rotate(q, a_imu).numpy() - np.array([0.0, 0.0, gravity])
    R = so3.quat_to_rotmat(q).numpy()
    tilt = np.degrees(np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0)))
    return {
        "duration": float(f.t[-1] - f.t[0]),
        "v_mean": float(speed.mean()),
        "v_max": float(speed.max()),
        "a_max": float(np.linalg.norm(acc, axis=1).max()),
        "tilt_max": float(tilt.max()),
    }


def trajectory_stats(flights: list[Flight]) -> dict[str, dict[str, float]]:
    """Statistics averaged over the runs of each trajectory."""
    by_traj: dict[str, list[dict[str, float]]] = {}
    for f in flights:
        by_traj.setdefault(f.trajectory, []).append(flight_stats(f))
    return {t: {k: float(np.mean([s[k] for s in runs])) for k in STAT_NAMES} for t, runs in by_traj.items()}


def stats_markdown(stats: dict[str, dict[str, float]], *, tolerance: float = 0.2, what: str = "simulated") -> str:
    """``what`` flights' (simulated, or the rig's) against the paper's statistics, side by side,
    with the ratio; ratios off 1 by more than ``tolerance`` are marked."""
    lines = [
        f"# Trajectory statistics: {what} flights against the paper",
        "",
        "Averaged over the runs of each trajectory. Speed from the velocity column, acceleration",
        f"from the accelerometer (R a_IMU - g), tilt from the quaternion. Each cell: {what} /",
        f"paper (ratio); a ratio outside 1 ± {tolerance:g} is marked ✗.",
        "",
        "| trajectory | " + " | ".join(STAT_LABELS[k] for k in STAT_NAMES) + " |",
        "|---|" + "---|" * len(STAT_NAMES),
    ]
    order = [t for t in PAPER_STATS if t in stats] + sorted(set(stats) - set(PAPER_STATS))
    n_off = 0
    for t in order:
        cells = []
        for k in STAT_NAMES:
            sim = stats[t][k]
            ref = PAPER_STATS.get(t, {}).get(k)
            if ref is None:
                cells.append(f"{sim:.2f}")
                continue
            r = sim / ref
            off = abs(r - 1) > tolerance
            n_off += off
            cells.append(f"{sim:.2f} / {ref:.2f} ({r:.2f}{' ✗' if off else ''})")
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    lines += ["", f"{n_off} of {sum(len(PAPER_STATS[t]) for t in order if t in PAPER_STATS)} figures outside ±{tolerance:.0%}."]
    return "\n".join(lines) + "\n"
