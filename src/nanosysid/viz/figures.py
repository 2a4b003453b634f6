"""The benchmark report's figures: MAE against horizon, 50-step-ahead predictions against the
ground truth, and the trajectory statistics of the dataset."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from nanosysid.protocol import Scores  # noqa: E402
from nanosysid.dataio import Flight, atomic_file  # noqa: E402
from nanosysid.metrics import QUANTITIES, UNITS  # noqa: E402
from nanosysid.viz.signals import SIGNALS, model_color, readable  # noqa: E402

__all__ = ["mae_horizon_figure", "predictions_figure", "trajectory_stats_figure"]

_TITLE = {"p": "position", "v": "velocity", "R": "orientation (geodesic)", "w": "angular velocity"}


def _save(fig, path: Path) -> None:
    with atomic_file(Path(path)) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def mae_horizon_figure(rows: Mapping[str, Scores], path: Path, reference: Sequence[str] = ("oracle",),
                       emphasis: Sequence[str] = ()) -> None:
    """Four panels (2 x 2), MAE of p, v, R, ω against the horizon h = 1..H, one line per model
    (log scale: the models span orders of magnitude), the legend below them. Reference rows (the
    oracle) are dashed; ``emphasis`` rows are drawn last and thicker, so no other line hides them."""
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    order = [n for n in rows if n not in emphasis] + [n for n in rows if n in emphasis]
    colors = {name: model_color(name, i) for i, name in enumerate(rows)}
    for ax, k in zip(axes.flat, QUANTITIES):
        for name in order:
            s = rows[name]
            h = np.arange(1, s.horizon + 1)
            ax.plot(h, s.mae[k], color=colors[name], lw=2.8 if name in emphasis else 1.5,
                    ls="--" if name in reference else "-", label=name, zorder=3 if name in emphasis else 2)
        ax.set_yscale("log")
        ax.set_title(f"MAE {_TITLE[k]}")
        ax.set_xlabel("horizon h [steps of 10 ms]")
        ax.set_ylabel(f"[{UNITS[k]}]")
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    by = dict(zip(labels, handles))
    fig.legend([by[n] for n in rows], list(rows), loc="lower center", ncol=min(len(rows), 4), fontsize=9,
               frameon=False)
    fig.tight_layout(rect=(0, 0.03 + 0.035 * ((len(rows) - 1) // 4 + 1), 1, 1))
    _save(fig, path)


def predictions_figure(flight: Flight, rows: Mapping[str, np.ndarray], path: Path, *, horizon: int,
                       window: tuple[float, float] = (20.0, 25.0), smooth: int = 20,
                       reference: Sequence[str] = ("oracle",)) -> None:
    """The ``horizon``-step-ahead predictions ``ŷ_{t|t-H}`` of each model (``rows``: name ->
    ``(T, 13)``, NaN where undefined) against the measured ``y_t`` over ``window`` seconds,
    12 panels: position, velocity, attitude (roll, pitch, yaw) and body rates. Like the
    paper's figure, each line is a centred rolling mean over ``smooth`` samples; reference
    rows (the oracle) are dashed."""
    t = flight.t - flight.t[0]
    sel = (t >= window[0]) & (t <= window[1])
    if not sel.any():
        sel = slice(None)

    def smoothed(a: np.ndarray) -> np.ndarray:
        return pd.DataFrame(a).rolling(smooth, center=True, min_periods=1).mean().to_numpy()

    truth = readable(flight.y)
    preds = {name: readable(y) for name, y in rows.items()}
    fig, axes = plt.subplots(4, 3, figsize=(14, 10), sharex=True)
    for r, k in enumerate(SIGNALS):
        label, unit, axes_names = SIGNALS[k]
        gt = smoothed(truth[k])
        for c in range(3):
            ax = axes[r, c]
            for i, (name, p) in enumerate(preds.items()):
                ax.plot(t[sel], smoothed(p[k])[sel, c], color=model_color(name, i), lw=1.1, label=name,
                        ls="--" if name in reference else "-")
            ax.plot(t[sel], gt[sel, c], color=model_color("truth"), lw=1.8, label="ground truth")
            ax.set_ylabel(f"{axes_names[c]} [{unit}]")
            ax.grid(True, alpha=0.3)
        axes[r, 0].set_title(label, loc="left", fontsize=10)
    for ax in axes[-1]:
        ax.set_xlabel(f"time [s], {flight.name}")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=9)
    fig.suptitle(f"{horizon}-step-ahead predictions ŷ(t | t−{horizon}) against the ground truth "
                 f"(centred rolling mean over {smooth} samples)", y=0.955, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    _save(fig, path)


def trajectory_stats_figure(stats: Mapping[str, Mapping[str, float]], paper: Mapping[str, Mapping[str, float]],
                            labels: Mapping[str, str], path: Path) -> None:
    """One panel per statistic: the dataset's value per trajectory (bars, mean over runs)
    beside the paper's (hatched)."""
    names = [k for k in labels if k != "duration"]
    trajs = [t for t in paper if t in stats] + sorted(set(stats) - set(paper))
    x = np.arange(len(trajs))
    fig, axes = plt.subplots(1, len(names), figsize=(3.6 * len(names), 3.6))
    for ax, k in zip(np.atleast_1d(axes), names):
        ours = [stats[t][k] for t in trajs]
        ref = [paper.get(t, {}).get(k, np.nan) for t in trajs]
        ax.bar(x - 0.2, ours, 0.4, color="C0", label="this dataset")
        ax.bar(x + 0.2, ref, 0.4, color="white", edgecolor="C1", hatch="//", label="paper (real flights)")
        ax.set_xticks(x, trajs)
        ax.set_title(labels[k])
        ax.grid(True, axis="y", alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=8)
    fig.suptitle("Trajectory statistics, mean over the runs of each trajectory", fontsize=11)
    fig.tight_layout()
    _save(fig, path)
