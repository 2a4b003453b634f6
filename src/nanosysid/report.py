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


def results_table_md(rows: Mapping[str, Scores], horizons: Sequence[int] = (1, 10, 50),
                     reference: Sequence[str] = ("oracle",)) -> str:
    """Markdown table: MAE at each horizon and the sum over h = 1..H, per quantity.

    The best (lowest) value of each column among the models is in bold; the ``reference``
    rows (the oracle, a limit rather than a model) do not compete.
    """
    if not rows:
        raise ValueError("no rows to tabulate")
    H = next(iter(rows.values())).horizon
    head = ["Model"]
    for k in QUANTITIES:
        head += [f"{_LABEL[k]} h={h} [{UNITS[k]}]" for h in horizons]
        head.append(f"*{_LABEL[k]} h=1:{H}*")
    values = np.array([_columns(s, horizons) for s in rows.values()])  # (models, columns)
    competing = np.array([name not in reference for name in rows])
    if competing.sum() > 1:
        best = np.nanmin(values[competing], axis=0)
    else:
        best = np.full(values.shape[1], np.nan)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, vals, comp in zip(rows, values, competing):
        cells = []
        for j, v in enumerate(vals):
            s = f"{v:.4f}"
            if (j + 1) % (len(horizons) + 1) == 0:
                s = f"*{s}*"
            cells.append(f"**{s}**" if comp and v == best[j] else s)
        label = name if comp else f"{name} (physical limit)"
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def load_scores(eval_dir, names):
    """Scores of each model from ``<eval_dir>/<name>/metrics.json``, in the given order."""
    import json
    from pathlib import Path

    from nanosysid.dataio import DataError

    rows = {}
    for name in names:
        f = Path(eval_dir) / name / "metrics.json"
        if not f.exists():
            raise DataError(f"{f}: no evaluation of model {name!r}")
        rows[name] = Scores.from_dict(json.loads(f.read_text()))
    return rows


def results_markdown(rows, horizons=(1, 10, 50)) -> str:
    """The benchmark table of all models, with a note on the oracle row."""
    note = ""
    if "oracle" in rows:
        note = ("\nThe `oracle` row integrates the simulator's true dynamics, hidden effects included: "
                "the physical limit on simulated data, not a model one could fit.\n")
    n = next(iter(rows.values())).n_windows
    return (f"# Benchmark results\n\nMAE at h = {', '.join(map(str, horizons))} and its sum over the horizon "
            f"(SimErr), mean over the test flights ({n} windows). Best value of each column in bold.\n\n"
            + results_table_md(rows, horizons) + note)
