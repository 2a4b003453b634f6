"""The discovery report: where the disagreement was, what was named and why, the gap it closed."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any


from nanosysid.dataio import atomic_file, json_text
from nanosysid.discover import CHANNELS, LIBRARY, VERDICTS, DiscoveryResult
from nanosysid.discover.analysis import BANDS, REGIMES
from nanosysid.metrics import QUANTITIES
from nanosysid.report.tables import results_table_md
from nanosysid.viz.figures import mae_horizon_figure
from nanosysid.viz.discovery import channel_figure, finding_figure

__all__ = ["write_report", "result_dict", "gap_closed", "verdicts_markdown"]

_QLABEL = {"p": "position", "v": "velocity", "R": "orientation", "w": "angular velocity"}


def gap_closed(result: DiscoveryResult, reference: str = "oracle") -> dict[str, float | None]:
    """Share of the gap between the nominal model's SimErr and the reference's (``"oracle"``:
    the true dynamics; ``"limit"``: the true dynamics of the state alone) the augmented model
    closes, per quantity (None without the reference, or where it is no better than the
    nominal model)."""
    if getattr(result, reference) is None:
        return {k: None for k in QUANTITIES}
    ref = getattr(result, reference)
    out = {}
    for k in QUANTITIES:
        gap = result.before.simerr[k] - ref.simerr[k]
        out[k] = None if gap <= 0 else float((result.before.simerr[k] - result.after.simerr[k]) / gap)
    return out


def _finding_dict(f) -> dict[str, Any]:
    return {"verdict": f.verdict, "name": f.name, "alternatives": list(f.alternatives), "channels": list(f.channels),
            "params": f.params, "evidence": f.evidence}


def result_dict(result: DiscoveryResult) -> dict[str, Any]:
    """JSON-ready summary (the figures' sample data left out)."""
    return {
        "format": "nanosysid-discovery-1",
        "model": result.name,
        "findings": [_finding_dict(f) for f in result.findings],
        "alpha": result.alpha,
        "floor": result.floor,
        "noise_floor": dict(zip(CHANNELS, (float(x) for x in result.noise))),
        "rounds": [[c.row() for c in candidates] for candidates in result.rounds],
        "vehicle": dataclasses.asdict(result.vehicle),
        "simerr": {"nominal": result.before.simerr, "discovered": result.after.simerr,
                   **({"oracle": result.oracle.simerr} if result.oracle else {}),
                   **({"state_limit": result.limit.simerr} if result.limit else {}),
                   **({"sindy": result.sindy["simerr"]} if result.sindy else {})},
        **({"sindy_terms": result.sindy["terms"]} if result.sindy else {}),
        "gap_closed": gap_closed(result),
        "gap_closed_state_limit": gap_closed(result, "limit"),
        "analysis": {k: v for k, v in result.analysis.items() if k != "scatter"},
    }


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def _unit(channel: str) -> str:
    return "mN" if channel.startswith("F") else "mN·m"


def _verdict_line(f) -> str:
    ev = f.evidence
    stats = (f"held-out gain {100 * ev['heldout_gain']:.2f} % of the nominal residual, size {ev['size']:.2f} noise "
             f"floors, z = {ev['z']:.1f}, "
             f"p = {ev['p']:.2g}, {ev['blocks_improved']} / {ev['blocks']} blocks improved")
    if f.verdict == "named":
        return f"**`{f.name}` named** on {', '.join(f.channels)} ({stats}; the best of its round on {100 * ev['stability']:.0f} % of the held-out folds)."
    if f.verdict == "ambiguous":
        alts = ", ".join(f"`{a}`" for a in f.alternatives)
        how = "; ".join(f"`{a}`: {t}" for a, t in ev["separate_by"].items() if t)
        return (f"**Ambiguous** on {', '.join(f.channels)}: {alts} explain it equally well ({stats}). The augmented "
                f"model uses `{ev['used']}`, the one with the lowest held-out residual. Flights that would tell them "
                f"apart: {how}.")
    if f.verdict == "not a function of the state":
        return (f"**Not a function of the state** on {', '.join(f.channels)}: {_fmt(1e3 * ev['rms'])} "
                f"{_unit(f.channels[0])} RMS ({ev['size']:.2f} noise floors, z = {ev['z']:.1f}, p = {ev['p']:.2g}, "
                f"{ev['blocks_improved']} / {ev['blocks']} blocks above the noise) that neither a library entry nor "
                f"the generic terms of the state capture, in the band {ev['band']}: a disturbance of its own (of time, "
                "a new realisation each flight) that no model of the state can predict.")
    where = (f" It is largest at {ev['regime']}, in the band {ev['band']}." if "regime" in ev else "")
    added = ("the augmented model adds those terms" if ev.get("added", True) else
             "its terms would make the rollouts on the training flights diverge, so the augmented model leaves them out")
    return (f"**Unnamed** disagreement on {', '.join(f.channels)} ({stats}): no library entry explains it; a sparse fit "
            f"of generic terms captures it, and {added}.{where}")


def verdicts_markdown(findings: list[dict[str, Any]]) -> str:
    """Discovery's verdicts (``result.json``'s ``findings``) as a short markdown list."""
    if not findings:
        return "**Discovery**: no disagreement stands above the noise floor."
    lines = ["**Discovery's verdicts**", ""]
    for f in findings:
        where = ", ".join(f["channels"])
        if f["verdict"] == "named":
            lines.append(f"- `{f['name']}` named ({where})")
        elif f["verdict"] == "ambiguous":
            lines.append(f"- ambiguous ({where}): " + " or ".join(f"`{a}`" for a in f["alternatives"]))
        elif f["verdict"] == "unnamed":
            lines.append(f"- unnamed ({where}): " + " + ".join(f["params"]))
        else:
            lines.append(f"- not a function of the state ({where})")
    return "\n".join(lines)


def write_report(result: DiscoveryResult, out: Path, *, nominal: str = "as given to discovery") -> None:
    """``report.md``, ``result.json``, ``verdicts.md`` (for the rerun recordings) and ``figures/`` in
    ``out``; ``nominal`` says where the nominal model's k_F and k_M come from."""
    out = Path(out)
    a = result.analysis
    figs = out / "figures"
    rows = {"nominal (physics_full)": result.before, f"discovered ({result.name})": result.after}
    if result.sindy is not None and result.sindy["scores"] is not None:
        rows["plain SINDy (generic terms, no names)"] = result.sindy["scores"]
    if result.limit is not None:
        rows["state limit (true dynamics of the state)"] = result.limit
    if result.oracle is not None:
        rows["oracle"] = result.oracle
    mae_horizon_figure(rows, figs / "mae_horizon.png")
    if a:
        channel_figure(a, figs / "channels.png")
    scatter = a.get("scatter", {}) if a else {}
    fig_of = {}
    for i, (label, d) in enumerate(scatter.items(), 1):
        fig_of[label] = f"figures/finding_{i}.png"
        finding_figure(label, d, out / fig_of[label])
    closed = gap_closed(result)

    L: list[str] = ["# Model-discrepancy discovery", ""]
    counts = {v: sum(f.verdict == v for f in result.findings) for v in VERDICTS}
    L += [f"The nominal model (rigid body with the torque equation, k_F and k_M {nominal}) "
          f"was compared with the measurements. {len(result.findings)} disagreements stand above the noise floor: "
          f"{counts['named']} named, {counts['ambiguous']} ambiguous, {counts['unnamed']} unnamed, "
          f"{counts['not a function of the state']} not a function of the state. The augmented model "
          f"`{result.name}` is scored below against the nominal model"
          + (" and the oracle (the simulator's true dynamics)." if result.oracle else "."), ""]
    L += ["| SimErr on the test flights | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |",
          "|---|" + "---|" * len(QUANTITIES)]
    for label, sc in rows.items():
        L.append(f"| {label} | " + " | ".join(_fmt(sc.simerr[k]) for k in QUANTITIES) + " |")
    if result.limit is not None:
        closed_limit = gap_closed(result, "limit")
        L.append("| share of the nominal–state-limit gap closed | "
                 + " | ".join("–" if closed_limit[k] is None else f"{100 * closed_limit[k]:.0f} %" for k in QUANTITIES)
                 + " |")
    if result.oracle is not None:
        L.append("| share of the nominal–oracle gap closed | "
                 + " | ".join("–" if closed[k] is None else f"{100 * closed[k]:.0f} %" for k in QUANTITIES) + " |")
    if result.limit is not None or result.oracle is not None:
        L += ["", "The state limit is the simulator's true dynamics without the effects that are not functions of the "
              "state (the turbulence and the rotors' thrust fluctuation, new in every flight): the best any model of "
              "the state can do. The oracle also replays each test flight's realisation of those, which no model "
              "can know; the part of the gap between the two is unknowable."]
    L += ["", "![MAE against horizon: nominal, discovered and oracle](figures/mae_horizon.png)", "",
          "*MAE against the prediction horizon on the test flights (log scale).*", ""]

    L += ["## Verdicts", ""]
    if not result.findings:
        L += ["No disagreement stands above the noise floor: the nominal model explains the measurements as well as "
              "the noise lets anything do.", ""]
    for f in result.findings:
        L += [_verdict_line(f), ""]
        if f.params:
            if f.verdict == "unnamed":
                L += ["| generic term (`~`: centred and scaled) | coefficient |", "|---|---|"]
                L += [f"| {k} | {v:.4g} |" for k, v in f.params.items()]
            else:
                desc = LIBRARY[f.entry].description
                L += [f"*{desc}*", "", "| coefficient | value | 95 % interval |", "|---|---|---|"]
                for k, v in f.params.items():
                    lo, hi = f.evidence["ci"][k]
                    L.append(f"| {k} | {v:.4g} | {lo:.4g} … {hi:.4g} |")
            L.append("")
        label = f.entry or f"{f.verdict} ({', '.join(f.channels)})"
        if label in fig_of:
            L += [f"![{label}: residual against its fitted contribution]({fig_of[label]})", "",
                  f"*{label}: its fitted contribution against the residual of {scatter[label]['channel']}, before "
                  "(everything else found removed: along the dashed line when it explains it) and after (what is "
                  "left); grey: ± the channel's noise floor.*", ""]
    if result.sindy is not None:
        L += [f"**Plain SINDy** (the same generic terms on the nominal residual, no names) keeps "
              f"{len(result.sindy['terms'])} terms" + ("; its rollouts diverge on the test flights." if result.sindy["diverged"]
                                                      else ".") , ""]

    if a:
        L += ["## Where the nominal model and the measurements disagree", "",
              "Measured body wrench: force `m a_IMU` from the accelerometer, torque `J dω/dt + ω × Jω` from "
              "the gyro (Savitzky-Golay derivative). Nominal: `[0, 0, k_F ΣΩ²]` and the mixer torques. RMS of "
              "measured minus predicted, in mN and mN·m, beside each channel's noise floor: the std of the "
              "measurement noise left after the smoothing, estimated from the data (accelerometer, gyro and "
              "rotor speeds) "
              f"({a['samples']['train']} training and {a['samples']['test']} test samples).", "",
              "| | " + " | ".join(f"{c} [{_unit(c)}]" for c in CHANNELS) + " |", "|---|" + "---|" * 6]
        L.append("| noise floor | " + " | ".join(f"{1e3 * x:.3g}" for x in a["noise"]) + " |")
        for part in ("train", "test"):
            for when in ("before", "after"):
                lab = f"RMS, {'training' if part == 'train' else 'test'} flights, {'nominal' if when == 'before' else 'with what was found'}"
                L.append(f"| {lab} | " + " | ".join(f"{1e3 * x:.3g}" for x in a[f"rms_{part}"][when]) + " |")
        L += ["", "![RMS of the residual per channel, before and after](figures/channels.png)", "",
              "*RMS of measured minus predicted wrench per channel, nominal model (red) and with what was found "
              "(green); black: the noise floor.*", ""]
        ro = a["rollouts"]
        L += ["**Which disagreement costs the benchmark most.** The nominal model's rollouts on the test "
              "flights, given one channel's measured residual as a known extra wrench: the share of the "
              "nominal SimErr that disappears.", "",
              "| channel given | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |", "|---|" + "---|" * 4]
        order = sorted(CHANNELS, key=lambda c: sum(ro["with_measured_channel"][c].values()))
        for c in order:
            r = ro["with_measured_channel"][c]
            L.append(f"| {c} | " + " | ".join(f"{100 * (1 - r[k] / ro['nominal'][k]):.1f} %" for k in QUANTITIES) + " |")
        worst = [CHANNELS.index(c) for c in a["regime_channels"]]
        L += ["", f"**By flight regime** (training flights, quartiles of each variable): RMS of the two channels that "
              f"carry the largest share of the SimErr ({', '.join(a['regime_channels'])}), nominal → with what was "
              "found.", ""]
        L += ["| regime | quartile range | " + " | ".join(f"{CHANNELS[c]} [{_unit(CHANNELS[c])}]" for c in worst)
              + " |", "|---|---|" + "---|" * len(worst)]
        for k in REGIMES:
            g = a["regimes"][k]
            for i in range(4):
                cells = [f"{1e3 * g['before'][i][c]:.3g} → {1e3 * g['after'][i][c]:.3g}" for c in worst]
                L.append(f"| {k} | {g['edges'][i]:.3g} – {g['edges'][i + 1]:.3g} | " + " | ".join(cells) + " |")
        L += ["", "**By frequency band** (training flights): share of each channel's nominal residual power in each "
              "band, nominal → with what was found.", "",
              "| band | " + " | ".join(CHANNELS) + " |", "|---|" + "---|" * 6]
        tot = [sum(a["bands"]["before"][i][c] for i in range(len(BANDS))) or 1.0 for c in range(6)]
        for i, (lo, hi) in enumerate(BANDS):
            L.append(f"| {lo:g}–{hi:g} Hz | " + " | ".join(
                f"{100 * a['bands']['before'][i][c] / tot[c]:.0f} % → {100 * a['bands']['after'][i][c] / tot[c]:.0f} %"
                for c in range(6)) + " |")
        L.append("")

    L += ["## How the verdicts were reached", "",
          "Every score is held out: the training samples are cut into blocks of a few seconds, dealt to folds, and "
          "each block's residual is measured with a fit on the other folds; channels are weighted by their noise "
          "floor. Forward selection over the library: each round, every candidate not yet chosen is added to the "
          "chosen ones. Under the hypothesis that a candidate explains nothing, its held-out gain on a block is as "
          "likely negative as positive; the one-sided Wilcoxon signed-rank test over the blocks gives a p-value, "
          f"multiplied by the number of candidates tried in the round (Bonferroni), which must be below "
          f"α = {result.alpha:g}; its size (the root of its held-out gain per sample, in noise floors) must be at "
          f"least {result.floor:g}. Coefficients with a physical sign (drag, rotor inertia) must not come out negative, and a correction must stay plausible (the inertia within 100 % of the nominal, the arm within 10 %, a rotor's spread within 25 %). "
          "Candidates the chosen one is not significantly better than (the same test on the difference of their "
          "held-out errors) make the finding ambiguous. A chosen entry must also explain at least half of what a "
          "generic sparse fit (pysindy's STLSQ over products of body velocity, rates, thrust and height) captures "
          "of the same disagreement; what remains is tested channel by channel with that generic fit, and is an "
          "unnamed finding where it captures significantly more than nothing. The rotor-speed delay is searched "
          "inside each fold. A coefficient's 95 % interval is a jackknife over the folds (each fold's fit leaves "
          "that fold out) with Student's t for their number; a named entry's stability is the share of the folds "
          "on which it beats every other eligible candidate of its round, held out.", ""]
    for i, candidates in enumerate(result.rounds, 1):
        L += [f"Round {i}:", "", "| candidate | held-out gain | size [noise floors] | z | p (adjusted) | blocks improved | "
              "plausible | eligible |", "|---|---|---|---|---|---|---|---|"]
        for r in (c.row() for c in candidates):
            L.append(f"| {r['candidate']} | {100 * r['heldout_gain']:.3f} % | {r['size']:.2f} | {r['z']:.1f} | {r['p']:.2g} | "
                     f"{r['blocks_improved']} / {r['blocks']} | {'yes' if r['plausible'] else 'no'} | "
                     f"{'yes' if r['eligible'] else 'no'} |")
        L.append("")
    L += ["## Benchmark table", "", results_table_md(rows), ""]
    with atomic_file(out / "report.md") as tmp:
        tmp.write_text("\n".join(L))
    summary = result_dict(result)
    with atomic_file(out / "result.json") as tmp:
        tmp.write_text(json_text(summary))
    with atomic_file(out / "verdicts.md") as tmp:
        tmp.write_text(verdicts_markdown(summary["findings"]) + "\n")

