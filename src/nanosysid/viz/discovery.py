"""Figures of the discovery report: the disagreement per channel before and after, and each
finding's fitted contribution against the residual it explains."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nanosysid.dataio import atomic_file, parse_flight_name  # noqa: E402
from nanosysid.effects import CHANNELS  # noqa: E402

__all__ = ["channel_figure", "finding_figure", "spectrum_figure"]


def _save(fig, path: Path) -> None:
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def channel_figure(a: dict[str, Any], path: Path) -> None:
    """RMS of the residual per channel (forces in mN, torques in mN·m), nominal and with what
    discovery added, on the training and test flights, beside each channel's noise floor."""
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.6))
    noise = 1e3 * np.asarray(a["noise"])
    for col, part in enumerate(("train", "test")):
        for j, (sl, unit) in enumerate(((slice(0, 3), "mN"), (slice(3, 6), "mN·m"))):
            ax = axes[2 * col + j]
            x = np.arange(3)
            ax.bar(x - 0.2, 1e3 * np.asarray(a[f"rms_{part}"]["before"])[sl], 0.4, color="C3", label="nominal model")
            ax.bar(x + 0.2, 1e3 * np.asarray(a[f"rms_{part}"]["after"])[sl], 0.4, color="C2", label="with what was found")
            ax.plot(x, noise[sl], "k_", ms=22, mew=2, label="noise floor")
            ax.set_xticks(x, CHANNELS[sl])
            ax.set_ylabel(f"RMS [{unit}]")
            ax.set_title(f"{'training' if part == 'train' else 'test'} flights", fontsize=9)
            ax.grid(True, axis="y", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)


def finding_figure(label: str, d: dict[str, Any], path: Path) -> None:
    """One finding: its fitted contribution against the residual it explains, before and after."""
    fig, ax = plt.subplots(figsize=(4.6, 4.0))
    unit = "mN" if d["channel"].startswith("F") else "mN·m"
    m = 1e3 * np.asarray(d["model"])
    ax.plot(m, 1e3 * np.asarray(d["residual_others_removed"]), ".", ms=2, alpha=0.35, color="C3",
            label="before: measured − model without it")
    ax.plot(m, 1e3 * np.asarray(d["residual_after"]), ".", ms=2, alpha=0.35, color="C2", label="after: what is left")
    lim = float(np.nanmax(np.abs(m))) if len(m) and np.nanmax(np.abs(m)) > 0 else 1.0
    ax.plot([-lim, lim], [-lim, lim], "k--", lw=1, label="its fitted contribution")
    nf = 1e3 * d["noise"]
    ax.axhspan(-nf, nf, color="0.85", zorder=0, label="± noise floor")
    ax.set_xlabel(f"fitted contribution to {d['channel']} [{unit}]")
    ax.set_ylabel(f"residual of {d['channel']} [{unit}]")
    ax.set_title(f"{label} ({d['verdict']})", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, markerscale=4)
    fig.tight_layout()
    _save(fig, path)


def spectrum_figure(a: dict[str, Any], channels: list[str], path: Path, title: str) -> None:
    """Power spectral density of the residual of ``channels`` on the training flights, nominal
    model and with what discovery found, one panel each."""
    sp = a["spectra"]
    f = np.asarray(sp["freq"])
    fig, axes = plt.subplots(1, len(channels), figsize=(4.4 * len(channels), 3.6), squeeze=False)
    for ax, ch in zip(axes[0], channels):
        c = CHANNELS.index(ch)
        unit = "mN" if ch.startswith("F") else "mN·m"
        ax.semilogy(f[1:], 1e6 * np.asarray(sp["before"][c])[1:], color="C3", label="nominal model")
        ax.semilogy(f[1:], 1e6 * np.asarray(sp["after"][c])[1:], color="C2", label="with what was found")
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"PSD [{unit}²/Hz]")
        ax.set_title(ch, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path)


def flight_means_figure(a: dict[str, Any], channels: list[str], path: Path, title: str) -> None:
    """Each training flight's mean residual of ``channels``, nominal model and with what
    discovery found, one panel each, the flights in the training set's order."""
    fm = a["flight_means"]
    x = np.arange(len(fm["flights"]))
    fig, axes = plt.subplots(1, len(channels), figsize=(4.4 * len(channels), 3.6), squeeze=False)
    for ax, ch in zip(axes[0], channels):
        c = CHANNELS.index(ch)
        unit = "mN" if ch.startswith("F") else "mN·m"
        ax.bar(x - 0.2, [1e3 * m[c] for m in fm["before"]], 0.4, color="C3", label="nominal model")
        ax.bar(x + 0.2, [1e3 * m[c] for m in fm["after"]], 0.4, color="C2", label="with what was found")
        ax.set_xticks(x, ["{} {}".format(*parse_flight_name(n)) for n in fm["flights"]], rotation=90, fontsize=6)
        ax.set_ylabel(f"flight's mean residual [{unit}]")
        ax.set_title(ch, fontsize=10)
        ax.axhline(0.0, color="k", lw=0.5)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path)
