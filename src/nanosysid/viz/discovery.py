"""Figures of the discovery report: the disagreement per channel before and after, and each
named effect's fitted contribution against the residual it explains."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nanosysid.dataio import atomic_file  # noqa: E402
from nanosysid.effects import CHANNELS  # noqa: E402

__all__ = ["channel_figure", "scatter_figure"]


def _save(fig, path: Path) -> None:
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def channel_figure(a: dict[str, Any], path: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6), sharey=True)
    x = np.arange(6)
    for ax, part in zip(axes, ("train", "test")):
        ax.bar(x - 0.2, a[f"rms_{part}"]["before"], 0.4, color="C3", label="nominal model")
        ax.bar(x + 0.2, a[f"rms_{part}"]["after"], 0.4, color="C2", label="with the named effects")
        ax.set_xticks(x, CHANNELS)
        ax.set_title(f"{'training' if part == 'train' else 'test'} flights")
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].set_ylabel("RMS of measured − predicted\n[std. dev. of the channel's nominal residual]")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)


def scatter_figure(scatter: dict[str, Any], path: Path) -> None:
    n = len(scatter)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 3.8), squeeze=False)
    for ax, (name, d) in zip(axes[0], scatter.items()):
        unit = "mN" if d["channel"].startswith("F") else "mN·m"
        m = 1e3 * np.asarray(d["model"])
        ax.plot(m, 1e3 * np.asarray(d["residual_others_removed"]), ".", ms=2, alpha=0.35, color="C3",
                label="before: measured − nominal (other effects removed)")
        ax.plot(m, 1e3 * np.asarray(d["residual_after"]), ".", ms=2, alpha=0.35, color="C2", label="after: what is left")
        lim = np.nanmax(np.abs(m)) if len(m) else 1.0
        ax.plot([-lim, lim], [-lim, lim], "k--", lw=1, label="the effect's prediction")
        ax.set_xlabel(f"{name}: fitted contribution to {d['channel']} [{unit}]")
        ax.set_ylabel(f"residual of {d['channel']} [{unit}]")
        ax.locator_params(nbins=5)
        ax.set_title(name)
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=7, markerscale=4)
    fig.tight_layout()
    _save(fig, path)
