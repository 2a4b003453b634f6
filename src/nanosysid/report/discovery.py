"""The discovery report: where the disagreement was, what was named and why, the gap it closed."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from nanosysid.dataio import atomic_file
from nanosysid.discover import CHANNELS, LIBRARY, DiscoveryResult
from nanosysid.discover.analysis import BANDS, REGIMES
from nanosysid.metrics import QUANTITIES
from nanosysid.report.tables import results_table_md
from nanosysid.viz.benchmark import mae_horizon_figure
from nanosysid.viz.discovery import channel_figure, scatter_figure

__all__ = ["write_report", "result_dict", "gap_closed"]

_QLABEL = {"p": "position", "v": "velocity", "R": "orientation", "w": "angular velocity"}


def gap_closed(result: DiscoveryResult) -> dict[str, float | None]:
    """Share of the nominal-to-oracle SimErr gap the augmented model closes, per quantity
    (None without an oracle, or where the oracle is no better than the nominal model)."""
    if result.oracle is None:
        return {k: None for k in QUANTITIES}
    out = {}
    for k in QUANTITIES:
        gap = result.before.simerr[k] - result.oracle.simerr[k]
        out[k] = None if gap <= 0 else float((result.before.simerr[k] - result.after.simerr[k]) / gap)
    return out


def result_dict(result: DiscoveryResult) -> dict[str, Any]:
    """JSON-ready summary (the figures' sample data left out)."""
    return {
        "model": result.name,
        "found": [{"name": f.name, "params": f.params, "evidence": f.evidence} for f in result.found],
        "threshold": result.threshold,
        "rounds": result.rounds,
        "vehicle": {"k_f": result.vehicle.k_f, "k_m": result.vehicle.k_m},
        "simerr": {"nominal": result.before.simerr, "discovered": result.after.simerr,
                   **({"oracle": result.oracle.simerr} if result.oracle else {})},
        "gap_closed": gap_closed(result),
        "analysis": {k: v for k, v in result.analysis.items() if k != "scatter"},
    }


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def write_report(result: DiscoveryResult, out: Path) -> None:
    """``report.md``, ``result.json`` and ``figures/`` in ``out``."""
    out = Path(out)
    a = result.analysis
    figs = out / "figures"
    rows = {"nominal (physics_full)": result.before, f"discovered ({result.name})": result.after}
    if result.oracle is not None:
        rows["oracle"] = result.oracle
    mae_horizon_figure(rows, figs / "mae_horizon.png")
    if a:
        channel_figure(a, figs / "channels.png")
    if a.get("scatter"):
        scatter_figure(a["scatter"], figs / "effects.png")
    closed = gap_closed(result)

    L: list[str] = ["# Model-discrepancy discovery", ""]
    named = ", ".join(f"`{f.name}`" for f in result.found) or "no effect"
    L += [f"The nominal model (rigid body with the torque equation, k_F and k_M identified on the "
          f"training flights) was compared with the measurements. The workflow named {named}; the "
          f"augmented model `{result.name}` is scored below against the nominal model"
          + (" and the oracle (the simulator's true dynamics)." if result.oracle else "."), ""]
    L += ["| SimErr on the test flights | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |",
          "|---|" + "---|" * len(QUANTITIES)]
    for label, s in rows.items():
        L.append(f"| {label} | " + " | ".join(_fmt(s.simerr[k]) for k in QUANTITIES) + " |")
    if result.oracle is not None:
        L.append("| share of the nominal–oracle gap closed | "
                 + " | ".join("–" if closed[k] is None else f"{100 * closed[k]:.0f} %" for k in QUANTITIES) + " |")
    L += ["", "![MAE against horizon: nominal, discovered and oracle](figures/mae_horizon.png)", "",
          "*MAE against the prediction horizon on the test flights (log scale).*", ""]

    if a:
        L += ["## Where the nominal model and the measurements disagree", "",
              "Measured body wrench: force `m a_IMU` from the accelerometer, torque `J dω/dt + ω × Jω` from "
              "the gyro (Savitzky-Golay derivative). Nominal: `[0, 0, k_F ΣΩ²]` and the mixer torques. Each "
              "channel is in units of the standard deviation of its nominal residual on the training flights "
              "(an RMS well above 1 means a constant part: a torque the rotor model never predicts) "
              f"({a['samples']['train']} training and {a['samples']['test']} test samples).", "",
              "| channel | " + " | ".join(CHANNELS) + " |", "|---|" + "---|" * 6]
        for part in ("train", "test"):
            for when in ("before", "after"):
                lab = f"RMS, {'training' if part == 'train' else 'test'} flights, {'nominal' if when == 'before' else 'with the effects'}"
                L.append(f"| {lab} | " + " | ".join(f"{x:.3f}" for x in a[f"rms_{part}"][when]) + " |")
        L += ["", "![RMS of the residual per channel, before and after](figures/channels.png)", "",
              "*RMS of measured minus predicted wrench per channel, nominal model (red) and with the named "
              "effects (green).*", ""]
        ro = a["rollouts"]
        L += ["**Which disagreement costs the benchmark most.** The nominal model's rollouts on the test "
              "flights, given one channel's measured residual as a known extra wrench: the share of the "
              "nominal SimErr that disappears.", "",
              "| channel given | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |", "|---|" + "---|" * 4]
        order = sorted(CHANNELS, key=lambda c: sum(ro["with_measured_channel"][c].values()))
        for c in order:
            r = ro["with_measured_channel"][c]
            L.append(f"| {c} | " + " | ".join(f"{100 * (1 - r[k] / ro['nominal'][k]):.1f} %" for k in QUANTITIES) + " |")
        L += ["", "**By flight regime** (training flights, quartiles of each variable): RMS of the two "
              "channels with the largest nominal residual, nominal → with the effects.", ""]
        worst = list(np.argsort(a["rms_train"]["before"])[::-1][:2])
        L += ["| regime | quartile range | " + " | ".join(CHANNELS[c] for c in worst) + " |", "|---|---|" + "---|" * len(worst)]
        for k in REGIMES:
            g = a["regimes"][k]
            for i in range(4):
                cells = [f"{g['before'][i][c]:.2f} → {g['after'][i][c]:.2f}" for c in worst]
                L.append(f"| {k} | {g['edges'][i]:.3g} – {g['edges'][i + 1]:.3g} | " + " | ".join(cells) + " |")
        L += ["", "**By frequency band** (training flights): residual power per band, nominal → with the effects.", "",
              "| band | " + " | ".join(CHANNELS) + " |", "|---|" + "---|" * 6]
        for i, (lo, hi) in enumerate(BANDS):
            L.append(f"| {lo:g}–{hi:g} Hz | " + " | ".join(
                f"{a['bands']['before'][i][c]:.3f} → {a['bands']['after'][i][c]:.3f}" for c in range(6)) + " |")
        L.append("")

    L += ["## Which effects were named, and why", "",
          "Forward selection over the candidate library: each round, every candidate not yet named is fitted "
          "together with those named (weighted least squares over the six channels, the nominal k_F and k_M "
          "refitted alongside), leaving one training flight out at a time. *Held-out gain* is the drop of the "
          "held-out residual sum of squares, as a share of the nominal residual's. A candidate is named when "
          f"its gain is at least {result.threshold:g} and it helps on at least two thirds of the held-out "
          "flights; the rounds stop when none does.", ""]
    for i, table in enumerate(result.rounds, 1):
        chosen = next((f.name for f in result.found if f.evidence.get("round") == i), None)
        note = ""
        if chosen and len(table) > 1 and table[1]["heldout_gain"] >= 0.9 * table[0]["heldout_gain"] > 0:
            note = (f" `{table[1]['candidate']}` explains almost as much ({table[1]['heldout_gain']:.4f} against "
                    f"{table[0]['heldout_gain']:.4f}): on these flights the data barely tell the two apart, and "
                    f"once `{chosen}` is in, little is left for it.")
        L += [f"Round {i}: " + (f"`{chosen}` named.{note}" if chosen else "no candidate clears the bar; the search stops."), "",
              "| candidate | held-out gain | flights improved |", "|---|---|---|"]
        for r in table:
            extra = f" (delay {1e3 * r['delay']:.0f} ms)" if "delay" in r else ""
            mark = " **named**" if r["candidate"] == chosen else ""
            L.append(f"| {r['candidate']}{extra}{mark} | {r['heldout_gain']:.4f} | {r['folds_improved']} / {r['folds']} |")
        L.append("")
    if result.found:
        L += ["**The named effects**, in the order they were named (coefficients fitted on all training flights, "
              "± jackknife standard error over the flights):", "",
              "| effect | what it is | coefficients | explained share | held-out gain |", "|---|---|---|---|---|"]
        for f in result.found:
            coefs = "<br>".join(f"{k} = {v:.4g} ± {f.evidence['stderr'][k]:.2g}" for k, v in f.params.items())
            L.append(f"| `{f.name}` | {LIBRARY[f.name].description} | {coefs} | "
                     f"{100 * f.evidence['explained_share']:.1f} % | {100 * f.evidence['heldout_gain']:.1f} % |")
        L.append("")
    if a.get("scatter"):
        L += ["![Residual against each named effect, before and after](figures/effects.png)", "",
              "*Each named effect's fitted contribution against the residual of the channel it acts on most: before "
              "(measured minus nominal, with the other named effects removed; along the dashed line when the "
              "effect explains it) and after (what is left).*", ""]
    L += ["## Benchmark table", "", results_table_md(rows), ""]
    with atomic_file(out / "report.md") as tmp:
        tmp.write_text("\n".join(L))
    with atomic_file(out / "result.json") as tmp:
        tmp.write_text(json.dumps(result_dict(result), indent=1) + "\n")
