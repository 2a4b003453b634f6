"""Result tables in the layout of the paper's results table."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from nanosysid.benchmark import Scores
from nanosysid.metrics import QUANTITIES, UNITS

__all__ = ["results_table_md"]

_LABEL = {"p": "MAE_p", "v": "MAE_v", "R": "MAE_R", "w": "MAE_ω"}


def _columns(scores: Scores, horizons: Sequence[int]) -> list[float]:
    row = []
    for k in QUANTITIES:
        row += [float(scores.mae[k][h - 1]) for h in horizons]
        row.append(scores.simerr[k])
    return row


def results_table_md(rows: Mapping[str, Scores], horizons: Sequence[int] = (1, 10, 50)) -> str:
    """Markdown table: MAE at each horizon and the sum over h = 1..H, per quantity.

    The best (lowest) value of each column is in bold.
    """
    if not rows:
        raise ValueError("no rows to tabulate")
    H = next(iter(rows.values())).horizon
    head = ["Model"]
    for k in QUANTITIES:
        head += [f"{_LABEL[k]} h={h} [{UNITS[k]}]" for h in horizons]
        head.append(f"*{_LABEL[k]} h=1:{H}*")
    values = np.array([_columns(s, horizons) for s in rows.values()])  # (models, columns)
    best = np.nanmin(values, axis=0) if len(rows) > 1 else np.full(values.shape[1], np.nan)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, vals in zip(rows, values):
        cells = []
        for j, v in enumerate(vals):
            s = f"{v:.4f}"
            if (j + 1) % (len(horizons) + 1) == 0:
                s = f"*{s}*"
            cells.append(f"**{s}**" if v == best[j] else s)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
