"""Figures of the campaign: recall against strength per effect, hidden against named, and the
gap closed over the worlds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from nanosysid.dataio import atomic_file  # noqa: E402

__all__ = ["recall_figure", "confusion_figure", "gap_figure"]


def _save(fig, path: Path) -> None:
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)


def recall_figure(table: pd.DataFrame, effects: Sequence[str], bins: Sequence[Sequence[float]], relevant: float,
                  path: Path) -> None:
    """Per world effect: each world that hides it (found or missed, against its strength), filled
    where it moves the nominal SimErr by more than ``relevant``, and the recall per strength bin."""
    n = len(effects)
    cols = min(4, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False, sharey=True)
    for ax, e in zip(axes.flat, effects):
        t = table[table[f"strength_{e}"] > 0]
        ax.set_title(e, fontsize=9)
        ax.set_yticks([0, 1], ["missed", "found"])
        ax.set_xscale("log")
        ax.set_xlim(0.25, 3.5)
        ax.set_xticks([0.3, 1, 3], ["0.3", "1", "3"])
        ax.minorticks_off()
        ax.set_ylim(-0.15, 1.15)
        ax.set_xlabel("strength")
        if t.empty:
            ax.text(0.5, 0.5, "no world hides it", ha="center", va="center", transform=ax.transAxes, fontsize=8)
            continue
        found = np.array([json.loads(r).get(e, False) for r in t["recalled"]], dtype=float)
        s = t[f"strength_{e}"].to_numpy()
        big = t[f"impact_{e}"].to_numpy() > relevant
        jitter = 0.04 * (np.arange(len(s)) % 3 - 1)
        ax.scatter(s[big], found[big] + jitter[big], c="C0", s=18, label=f"moves SimErr > {100 * relevant:.0f} %")
        ax.scatter(s[~big], found[~big] + jitter[~big], facecolors="none", edgecolors="C7", s=18, label="smaller")
        for lo, hi in bins:
            m = big & (s >= lo) & (s <= hi)
            if m.any():
                ax.plot([lo, hi], [found[m].mean()] * 2, "C3-", lw=2)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="center right")
    fig.suptitle("Recall against strength (red: recall of the relevant worlds per strength bin)", fontsize=10)
    fig.tight_layout()
    _save(fig, path)


def confusion_figure(table: pd.DataFrame, effects: Sequence[str], entries: Sequence[str], path: Path) -> None:
    """How often each library entry is named (or offered in an ambiguous verdict) in worlds that
    hide each effect; the last row, worlds that hide nothing."""
    hidden = [*effects, "user effect", "nothing"]
    m = np.zeros((len(hidden), len(entries)))
    counts = np.zeros(len(hidden))
    for _, r in table.iterrows():
        offered = set(json.loads(r["named"])) | {a for alts in json.loads(r["ambiguous"]) for a in alts}
        present = [e for e in effects if r[f"strength_{e}"] > 0] + (["user effect"] if r["user"] else [])
        for h in present or ["nothing"]:
            i = hidden.index(h)
            counts[i] += 1
            for n in offered:
                m[i, entries.index(n)] += 1
    share = m / np.maximum(counts, 1)[:, None]
    fig, ax = plt.subplots(figsize=(0.45 * len(entries) + 3, 0.4 * len(hidden) + 2))
    im = ax.imshow(share, cmap="Blues", vmin=0, vmax=1, aspect="auto")
    for i in range(len(hidden)):
        for j in range(len(entries)):
            if m[i, j]:
                ax.text(j, i, f"{int(m[i, j])}", ha="center", va="center", fontsize=7,
                        color="white" if share[i, j] > 0.5 else "black")
    ax.set_xticks(range(len(entries)), entries, rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(len(hidden)), [f"{h} ({int(c)})" for h, c in zip(hidden, counts)], fontsize=8)
    ax.set_xlabel("library entry named or offered")
    ax.set_ylabel("hidden in the world (worlds)")
    fig.colorbar(im, ax=ax, label="share of the worlds")
    fig.tight_layout()
    _save(fig, path)


def gap_figure(table: pd.DataFrame, path: Path) -> None:
    """The share of the reachable nominal-to-oracle gap closed, discovery and plain SINDy."""
    fig, ax = plt.subplots(figsize=(6, 3.4))
    edges = np.linspace(-0.5, 1.1, 17)
    for col, label, color in (("gap_closed", "discovery", "C2"), ("sindy_gap_closed", "plain SINDy", "C7")):
        v = table[col].to_numpy()
        v = np.clip(v[~np.isnan(v)], edges[0], edges[-1])  # a diverged model: -inf, the left edge
        ax.hist(v, edges, histtype="stepfilled" if col == "gap_closed" else "step", color=color, alpha=0.8,
                lw=2, label=f"{label} ({len(v)} worlds)")
    ax.axvline(0.5, color="k", ls=":", lw=1)
    ax.set_xlabel("share of the reachable gap closed (clipped to -0.5..1.1)")
    ax.set_ylabel("worlds")
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
