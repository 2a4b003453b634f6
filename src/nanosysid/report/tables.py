"""The benchmark report: result and cost tables in the layouts of the paper's tables, as
Markdown and LaTeX, and the MAE curves as a DVC plot file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from nanosysid.protocol import Scores
from nanosysid.errors import DataError
from nanosysid.export import MAX_CYCLES_PER_INSTRUCTION
from nanosysid.metrics import QUANTITIES, UNITS
from nanosysid.report.paper import PAPER_COST

__all__ = ["results_table_md", "results_table_tex", "cost_table_md", "cost_table_tex", "load_scores",
           "load_costs", "benchmark_markdown", "mae_csv"]

_LABEL = {"p": "MAE_p", "v": "MAE_v", "R": "MAE_R", "w": "MAE_ω"}
_TEX_LABEL = {"p": r"\mathrm{MAE}_{p,h}", "v": r"\mathrm{MAE}_{v,h}", "R": r"\mathrm{MAE}_{R,h}",
              "w": r"\mathrm{MAE}_{\omega,h}"}

def _horizons(rows: Mapping[str, Scores], horizons: Sequence[int]) -> tuple[int, list[int]]:
    """The rows' one horizon H, and the table's horizons within it (an evaluation shortened to
    H = 20 has no MAE at h = 50 to show).

    Raises:
        DataError: rows scored at different horizons, whose sums are not comparable.
    """
    if not rows:
        raise ValueError("no rows to tabulate")
    hs = {name: s.horizon for name, s in rows.items()}
    if len(set(hs.values())) > 1:
        raise DataError("scores of different horizons cannot share a table: " + ", ".join(
            f"{n} H = {h}" for n, h in hs.items()) + "; evaluate every model at one eval.horizon")
    H = next(iter(hs.values()))
    return H, [h for h in horizons if 1 <= h <= H]


def _results_cells(rows: Mapping[str, Scores], horizons: Sequence[int], reference: Sequence[str]):
    """Values ``(models, columns)``, which of them is the best of its column, and which rows
    compete (the ``reference`` rows, the oracle, are a limit rather than a model)."""
    cols = []
    for s in rows.values():
        row = []
        for k in QUANTITIES:
            row += [float(s.mae[k][h - 1]) for h in horizons]
            row.append(s.simerr[k])
        cols.append(row)
    values = np.array(cols)  # (models, quantities * (horizons + 1))
    competing = np.array([name not in reference for name in rows])
    best = np.zeros_like(values, dtype=bool)
    if competing.sum() > 1:
        best = competing[:, None] & (values == np.nanmin(values[competing], axis=0))
    return values, best, competing


def results_table_md(rows: Mapping[str, Scores], horizons: Sequence[int] = (1, 10, 50),
                     reference: Sequence[str] = ("oracle",)) -> str:
    """Markdown table: MAE at each horizon and the sum over h = 1..H, per quantity.

    The best (lowest) value of each column among the models is in bold; the ``reference``
    rows (the oracle, a limit rather than a model) do not compete.
    """
    H, horizons = _horizons(rows, horizons)
    head = ["Model"]
    for k in QUANTITIES:
        head += [f"{_LABEL[k]} h={h} [{UNITS[k]}]" for h in horizons]
        head.append(f"*{_LABEL[k]} h=1:{H}*")
    values, best, competing = _results_cells(rows, horizons, reference)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for i, name in enumerate(rows):
        cells = []
        for j, v in enumerate(values[i]):
            s = f"{v:.4f}"
            if (j + 1) % (len(horizons) + 1) == 0:
                s = f"*{s}*"
            cells.append(f"**{s}**" if best[i, j] else s)
        label = name if competing[i] else f"{name} (physical limit)"
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _tex_escape(s: str) -> str:
    return s.replace("_", r"\_")


def results_table_tex(rows: Mapping[str, Scores], horizons: Sequence[int] = (1, 10, 50),
                      reference: Sequence[str] = ("oracle",)) -> str:
    """The results table as a LaTeX ``table*`` (booktabs), the paper's layout."""
    if not rows:
        raise ValueError("no rows to tabulate")
    H, horizons = _horizons(rows, horizons)
    n = len(horizons) + 1
    values, best, competing = _results_cells(rows, horizons, reference)
    heads = [rf"\multicolumn{{{n}}}{{c{'|' if i < len(QUANTITIES) - 1 else ''}}}{{${_TEX_LABEL[k]}$ [{UNITS[k]}]}}"
             for i, k in enumerate(QUANTITIES)]
    sub = [rf"$h{{=}}{h}$" for h in horizons] + [rf"\textit{{$h{{=}}1{{:}}{H}$}}"]
    lines = [
        r"\begin{table*}[t]", r"\centering",
        rf"\caption{{Numerical performance at $h={','.join(map(str, horizons))}$. The italic column is the "
        rf"simulation error (sum of the MAE over $h=1..{H}$). Best value of each column in bold.}}",
        r"\setlength{\tabcolsep}{3pt}", r"\scriptsize",
        r"\begin{tabular}{l|" + "|".join(["c" * n] * len(QUANTITIES)) + "}",
        r"\toprule",
        " & " + " & ".join(heads) + r" \\",
        "Model & " + " & ".join(sub * len(QUANTITIES)) + r" \\",
        r"\midrule",
    ]
    for i, name in enumerate(rows):
        cells = []
        for j, v in enumerate(values[i]):
            s = f"{v:.4f}"
            if (j + 1) % n == 0:
                s = rf"\textit{{{s}}}"
            cells.append(rf"\textbf{{{s}}}" if best[i, j] else s)
        label = _tex_escape(name) if competing[i] else rf"{_tex_escape(name)} (physical limit)"
        lines.append(f"{label} & " + " & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\label{tab:numerical_performance}", r"\end{table*}"]
    return "\n".join(lines) + "\n"


def _fmt(x: float | None, spec: str) -> str:
    return "–" if x is None else format(x, spec)


# Cost-table columns: header, key in a model's cost record, format. The microcontroller
# columns appear only when some model has them (the export stages write them).
_COST_COLUMNS = [
    ("#params [k]", "params_k", ".1f"),
    ("Compute [kFLOPs]", "kflops", ".1f"),
    ("Instructions / step", "instructions", ",.0f"),
    ("T at 168 MHz [ms], at least", "t_est_ms", ".3f"),
    ("at most", "t_max_ms", ".3f"),
    ("ONNX operators", "onnx_operators", ",.0f"),
    ("Flash [kB]", "flash_kb", ".1f"),
    ("RAM [kB]", "ram_kb", ".1f"),
    ("Paper T_inf [ms]", "paper_t_inf_ms", ".2f"),
]


def _cost_columns(costs: Mapping[str, Mapping[str, Any]]):
    mcu = any(c.get("instructions") is not None for c in costs.values())
    return [c for c in _COST_COLUMNS if mcu or c[1] in ("params_k", "kflops", "paper_t_inf_ms")]


def cost_table_md(costs: Mapping[str, Mapping[str, Any]]) -> str:
    """The model-cost table in the layout of the paper's parameter table, one row per model."""
    cols = _cost_columns(costs)
    lines = ["| Model | " + " | ".join(c[0] for c in cols) + " |", "|---|" + "---|" * len(cols)]
    for name, c in costs.items():
        lines.append(f"| {name} | " + " | ".join(_fmt(c.get(key), spec) for _, key, spec in cols) + " |")
    return "\n".join(lines) + "\n"


def cost_table_tex(costs: Mapping[str, Mapping[str, Any]]) -> str:
    """The model-cost table as LaTeX."""
    cols = _cost_columns(costs)
    lines = [r"\begin{table}[t]", r"\centering",
             r"\caption{Trainable parameters, floating-point operations per step and, where measured, "
             r"the cost of one step on the STM32F405.}",
             r"\begin{tabular}{l|" + "c" * len(cols) + "}", r"\toprule",
             "Model & " + " & ".join(_tex_escape(c[0]).replace("#", r"\#") for c in cols) + r" \\", r"\midrule"]
    for name, c in costs.items():
        lines.append(f"{_tex_escape(name)} & "
                     + " & ".join(_fmt(c.get(key), spec).replace("–", "--") for _, key, spec in cols) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\label{tab:models_params}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def load_scores(eval_dir: str | Path, names: Sequence[str]) -> dict[str, Scores]:
    """Scores of each model from ``<eval_dir>/<name>/scores.json``, in the given order."""
    rows = {}
    for name in names:
        f = Path(eval_dir) / name / "scores.json"
        if not f.exists():
            raise DataError(f"{f}: no evaluation of model {name!r}")
        try:
            rows[name] = Scores.from_dict(json.loads(f.read_text()))
        except (ValueError, KeyError, TypeError) as e:  # cut short, hand-edited or of another format
            raise DataError(f"{f}: not the evaluation's scores ({type(e).__name__}: {e}); rerun the evaluate stage "
                            f"of {name!r}") from None
    _horizons(rows, ())  # one horizon, checked before any figure or table is written
    return rows


def load_costs(eval_dir: str | Path, names: Sequence[str], export_dir: str | Path | None = None) -> dict[str, dict[str, Any]]:
    """Each model's cost record: parameters and FLOPs from its evaluation's ``metrics.json``,
    the microcontroller figures from ``<export_dir>/<name>.json`` where that exists, and the
    paper's measured T_inf."""
    out = {}
    for name in names:
        f = Path(eval_dir) / name / "metrics.json"
        if not f.exists():
            raise DataError(f"{f}: no evaluation of model {name!r}")
        cost = json.loads(f.read_text()).get("cost", {})
        rec: dict[str, Any] = {
            "params_k": None if cost.get("params") is None else cost["params"] / 1e3,
            "kflops": None if cost.get("flops") is None else cost["flops"] / 1e3,
            "paper_t_inf_ms": PAPER_COST.get(name, {}).get("t_inf_ms"),
        }
        mcu = Path(export_dir) / f"{name}.json" if export_dir else None
        if mcu is not None and mcu.exists():
            m = json.loads(mcu.read_text())
            rec.update({k: m.get(k) for k in ("instructions", "t_est_ms", "t_max_ms", "onnx_operators", "flash_kb",
                                              "ram_kb")})
        out[name] = rec
    return out


def mae_csv(rows: Mapping[str, Scores]) -> str:
    """The MAE curves in long form, one row per model and horizon (the DVC plot's data)."""
    lines = ["h,model," + ",".join(QUANTITIES)]
    for name, s in rows.items():
        for h in range(s.horizon):
            lines.append(f"{h + 1},{name}," + ",".join(f"{s.mae[k][h]:.8g}" for k in QUANTITIES))
    return "\n".join(lines) + "\n"


def _paper_time_lines(costs: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Where the paper's T_inf lies beyond the bounds of the step's time: by how much, and what the
    paper ran that this product does not (each model's graph through ST's Edge AI runtime, on
    the STM32EdgeAI Developer Cloud's boards; here the step is C generated for it)."""
    out = []
    for name, c in costs.items():
        paper, lo, hi, ops = (c.get(k) for k in ("paper_t_inf_ms", "t_est_ms", "t_max_ms", "onnx_operators"))
        if paper is None or lo is None or hi is None:
            continue
        if paper > hi:
            per = f"; its ONNX graph has {ops:,} operators, {paper / ops * 1e3:.1f} µs an operator" if ops else ""
            out.append(f"- `{name}`: the paper's {paper:g} ms is {paper / hi:.0f} times this step's most{per}. The "
                       "paper ran each model's graph through ST's Edge AI runtime, which dispatches operator after "
                       "operator; here the step is straight-line C.")
        elif paper < lo:
            out.append(f"- `{name}`: the paper's {paper:g} ms is below this step's least ({lo:.3f} ms).")
        else:
            out.append(f"- `{name}`: the paper's {paper:g} ms lies within this step's bounds.")
    if {"physics", "residual", "phys_res"} <= costs.keys() and all(
            costs[m].get("paper_t_inf_ms") is not None for m in ("physics", "residual", "phys_res")):
        a, b, s = (costs[m]["paper_t_inf_ms"] for m in ("physics", "residual", "phys_res"))
        out.append(f"- The paper's `phys_res` ({s:g} ms) is its `physics` plus its `residual` ({a:g} + {b:g} = "
                   f"{a + b:g} ms): the physics graph's cost carried whole into the hybrid.")
    return ["", *out, ""] if out else []


def benchmark_markdown(rows: Mapping[str, Scores], costs: Mapping[str, Mapping[str, Any]],
                       horizons: Sequence[int], figures: Sequence[tuple[str, str]]) -> str:
    """``reports/benchmark.md``: the results table, the cost table and the figures
    (``(relative path, caption)`` pairs)."""
    n = next(iter(rows.values())).n_windows
    parts = [
        "# Benchmark report", "",
        "## Multi-step prediction on the test flights", "",
        f"MAE at h = {', '.join(map(str, horizons))} and its sum over the horizon (SimErr, in italics), "
        f"mean over the test flights ({n} windows). Best value of each column in bold.", "",
        results_table_md(rows, horizons),
    ]
    if "oracle" in rows:
        parts += ["The `oracle` row integrates the simulator's true dynamics, hidden effects included: "
                  "the physical limit on simulated data, not a model one could fit.", ""]
    if "discovered" in rows and "physics_full" in rows:
        parts += ["The `discovered` row is the discover stage's augmented model: the nominal vehicle with the effects "
                  "it found, its torque equation integrated only about the body axes where held-out rollouts of the "
                  "training flights beat holding the angular velocity as the paper's `physics` row does; read it "
                  "against the better of `physics` and `physics_full` in each quantity. The discovery report says "
                  "which axes and why, and sets it beside the other rows.", ""]
    parts += [
        "## Cost of one step", "",
        "Trainable parameters and floating-point operations per prediction step (the LSTM: one "
        "recurrent step; its initialisation runs once per rollout). For the networks, FLOPs are torch's "
        "count of the matrix products, a multiply-add counted as 2 (the paper's compute column appears to "
        "count multiply-adds); for the physics step, the exact count of every operation in its generated C. "
        "Where the models have been run on the emulated STM32F405, the instructions executed per step, "
        "the time they take at 168 MHz, and the flash and RAM of the step are given beside the paper's T_inf, "
        "measured on a physical STM32 MCU. The emulator has no timing model of the Cortex-M4 (its pipeline, "
        "the flash's wait states), so cycles are not counted: the time lies between one cycle an instruction "
        f"and {MAX_CYCLES_PER_INSTRUCTION} (VDIV.F32 and VSQRT.F32 take 14, and a miss of the flash's cache "
        "adds 5 wait states). The "
        "ONNX operators are the exported graph's, constants left out.", "",
        cost_table_md(costs), *_paper_time_lines(costs),
        "## Figures", "",
    ]
    for path, caption in figures:
        parts += [f"![{caption}]({path})", "", f"*{caption}*", ""]
    return "\n".join(parts)
