"""The discovery report: where the disagreement was, what was named and why, the gap it closed."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from nanosysid.dataio import atomic_file, json_text
from nanosysid.discover import CHANNELS, LIBRARY, VERDICTS, DiscoveryResult
from nanosysid.discover.analysis import BANDS, REGIMES
from nanosysid.discover.sources import AGREE, HISTORY_REPEAT
from nanosysid.discover.stats import spread
from nanosysid.effects import SLOW_TIMES
from nanosysid.metrics import QUANTITIES
from nanosysid.report.tables import results_table_md
from nanosysid.viz.figures import mae_horizon_figure
from nanosysid.viz.discovery import channel_figure, finding_figure, flight_means_figure, spectrum_figure

__all__ = ["write_report", "result_dict", "gap_closed", "verdicts_markdown", "headline", "base_text"]

_QLABEL = {"p": "position", "v": "velocity", "R": "orientation", "w": "angular velocity"}


def gap_closed(result: DiscoveryResult, reference: str = "oracle") -> dict[str, float | None]:
    """Share of the gap between the best nominal row's SimErr
    (:attr:`~nanosysid.discover.DiscoveryResult.best_nominal`) and the reference's (``"oracle"``:
    the true dynamics; ``"limit"``: the true dynamics of the state alone; ``"held_limit"``: those
    with the angular velocity held) the augmented model closes, per quantity (None without the
    reference, or where it is no better than the best nominal row)."""
    if getattr(result, reference) is None:
        return {k: None for k in QUANTITIES}
    ref, best = getattr(result, reference), result.best_nominal
    out = {}
    for k in QUANTITIES:
        gap = best[k] - ref.simerr[k]
        out[k] = None if gap <= 0 else float((best[k] - result.after.simerr[k]) / gap)
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
        "base": result.base,
        "simerr": {"nominal": result.before.simerr, "discovered": result.after.simerr,
                   **({"physics": result.held_rate.simerr} if result.held_rate is not None else {}),
                   "best_nominal": result.best_nominal,
                   **({"oracle": result.oracle.simerr} if result.oracle else {}),
                   **({"state_limit": result.limit.simerr} if result.limit else {}),
                   **({"held_state_limit": result.held_limit.simerr} if result.held_limit else {}),
                   **({"sindy": result.sindy["simerr"]} if result.sindy else {})},
        **({"sindy_terms": result.sindy["terms"]} if result.sindy else {}),
        "k_m": result.k_m,
        "dropped": result.dropped,
        "folds": result.folds,
        "pairs": result.pairs,
        "gap_closed": gap_closed(result),
        "gap_closed_state_limit": gap_closed(result, "limit"),
        "gap_closed_held_state_limit": gap_closed(result, "held_limit"),
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
    folds = _folds_text(ev)
    if f.verdict == "named":
        return (f"**`{f.name}` named** on {', '.join(f.channels)} ({stats}; the best of its round on "
                f"{100 * ev['stability']:.0f} % of the held-out folds{folds}).")
    if f.verdict == "unstable":
        if f.entry:
            what = (f"`{f.entry}`" + (f" (or {', '.join(f'`{a}`' for a in f.alternatives[1:])})"
                                      if len(f.alternatives) > 1 else "") + f" would be {ev.get('was', 'named')}")
            left = "it is not named, and the augmented model leaves it out"
        else:
            what = f"the residual would be called {ev.get('was', 'unnamed')}"
            left = "no verdict is given" + (", and the augmented model leaves its generic terms out"
                                            if ev.get("was") == "unnamed" and not ev.get("repeats") else "")
        return (f"**Unstable** on {', '.join(f.channels)}: {what} on all the training flights ({stats}), but the "
                f"search reaches it on only {ev['folds']['held']} of the {ev['folds']['of']} folds that leave one "
                f"flight out (not on {', '.join(ev['folds']['missed'])}): it rests on some of the flights, not on all, "
                f"so {left}.")
    if f.verdict == "undetermined":
        coef = "; ".join(f"{k} {_fmt(ev['ci'][k][0])} … {_fmt(ev['ci'][k][1])}" for k in f.params)
        return (f"**Undetermined** on {', '.join(f.channels)}: `{f.name}` improves the held-out fit ({stats}), but "
                f"every coefficient's 95 % interval holds zero ({coef}): the data do not exclude that the effect is "
                "absent, so it is not named. The augmented model still uses it (every flight carries it).")
    if f.verdict == "ambiguous":
        alts = ", ".join(f"`{a}`" for a in f.alternatives)
        how = _separate_text(ev["separate_by"])
        return (f"**Ambiguous** on {', '.join(f.channels)}: {alts} explain it equally well ({stats}). The augmented "
                f"model uses `{ev['used']}`, the one with the lowest held-out residual. Flights that would tell them "
                f"apart: {how}.")
    if f.verdict == "not a function of the state":
        return (f"**Not a function of the state** on {', '.join(f.channels)}: {_fmt(1e3 * ev['rms'])} "
                f"{_unit(f.channels[0])} RMS ({ev['size']:.2f} noise floors, z = {ev['z']:.1f}, p = {ev['p']:.2g}, "
                f"{ev['blocks_improved']} / {ev['blocks']} blocks above the noise{folds}) that neither a library "
                f"entry nor the generic terms of the state capture, in the band {ev['band']}. "
                + _source_text(ev.get("source")))
    if ev.get("repeats"):
        return (f"**Unnamed** disagreement on {', '.join(f.channels)}: {_fmt(1e3 * ev['rms'])} {_unit(f.channels[0])} "
                f"RMS ({ev['size']:.2f} noise floors, z = {ev['z']:.1f}, p = {ev['p']:.2g}{folds}) that neither a "
                f"library entry nor the generic terms of the state capture, in the band {ev['band']}. "
                + _source_text(ev["source"]) + " Not in the augmented model.")
    if ev.get("saturated"):
        return (f"**Unnamed** disagreement on {', '.join(f.channels)} ({stats}{folds}): no entry was significant "
                f"alone, but every state entry of the library fitted at once, with the generic terms, leaves no "
                f"more than the noise (p = {ev['saturated_p']:.2g}): a function of the state, left out of the "
                "augmented model.")
    where = (f" It is largest at {ev['regime']}, in the band {ev['band']}." if "regime" in ev else "")
    added = ("the augmented model adds those terms" if ev.get("added", True) else
             "its terms would make the rollouts on the training flights diverge, so the augmented model leaves them out")
    return (f"**Unnamed** disagreement on {', '.join(f.channels)} ({stats}{folds}): no library entry explains it; a "
            f"sparse fit of generic terms captures it, and {added}.{where}")


def _separate_text(separate_by: Mapping[str, str]) -> str:
    """The flights that would tell rivals apart: each rival's own manoeuvre, or, where the library
    gives them one manoeuvre, that manoeuvre once (it excites them differently)."""
    texts = {t for t in separate_by.values() if t}
    if len(texts) == 1:
        return f"{texts.pop()}, which excite {' and '.join(f'`{a}`' for a in separate_by)} differently"
    return "; ".join(f"`{a}`: {t}" for a, t in separate_by.items() if t)


def _folds_text(ev: dict[str, Any]) -> str:
    fo = ev.get("folds")
    if not fo:
        return ""
    return f"; reached on {fo['held']} of the {fo['of']} folds that leave one training flight out"


def _source_text(src: dict[str, Any] | None) -> str:
    """What a residual that no function of the state explains is a function of, with the evidence."""
    if not src:
        return "It is a disturbance of its own that no model of the state can predict."
    if src["source"] == "undecided":
        return (f"What it is a function of is undecided: {src['why']}; fly one reference twice to tell a function "
                "of time from one of the input history.")
    within = ("" if src.get("within_share") is None else
              f", {100 * src['within_share']:.0f} % with each flight's own mean removed (runs flown back to back can "
              "share a constant of the flight)")
    shared = (f"{100 * src['repeat_share']:.0f} % of its power above the noise repeats between runs of one reference "
              f"(signed-rank z = {src['z']:.1f}, p = {src['p']:.2g} over {src['blocks']} blocks){within}")
    if src["source"] == "time":
        return (f"**A function of time**: {shared}, so most of it is a new realisation every flight, a disturbance "
                "no model of the measured signals can predict.")
    return (f"**A function of the reference**: {shared}, so it is not time: it follows what the reference makes of "
            "the flight, through the rotor speeds' history beyond the library's lags or a state signal the library "
            "lacks (no test here tells the two apart).")


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
        elif f["verdict"] == "unnamed" and f["evidence"].get("repeats"):
            lines.append(f"- unnamed ({where}): repeats with the reference")
        elif f["verdict"] == "unnamed":
            lines.append(f"- unnamed ({where}): " + " + ".join(f["params"]))
        elif f["verdict"] == "unstable":
            what = f"`{f['name'] or f['alternatives'][0]}`" if f["name"] or f["alternatives"] else \
                f"{f['evidence'].get('was', 'unnamed')}"
            lines.append(f"- unstable ({where}): {what} not reached on 80 % of the folds that leave one flight out")
        elif f["verdict"] == "undetermined":
            lines.append(f"- undetermined ({where}): `{f['name']}`, every coefficient's interval holds zero")
        else:
            src = (f["evidence"].get("source") or {}).get("source")
            lines.append(f"- not a function of the state ({where})" + (f": a function of {src}" if src and src != "undecided" else ""))
    return "\n".join(lines)


def horizon_caption(rows: Mapping[str, Any]) -> str:
    """The MAE figure's caption: the kinds of row it draws (an oracle only where there is one)."""
    kinds = [k for k, prefix in (("nominal", "nominal"), ("discovered", "discovered"), ("plain SINDy", "plain SINDy"),
                                 ("state limit", "state limit"), ("oracle", "oracle"))
             if any(r.startswith(prefix) for r in rows)]
    return kinds[0] if len(kinds) == 1 else ", ".join(kinds[:-1]) + " and " + kinds[-1]


def figure_lines(label: str, path: str, channel: str, shown: set[str]) -> list[str]:
    """A finding's figure, or where an earlier finding of the same label showed it (the generic
    terms' sparse fit is one per channel: every unnamed finding on that channel has the same
    contribution), a line that points to it instead of a second copy."""
    if path in shown:
        return [f"*Its contribution is the same fit as the {label} finding above ([figure]({path})): the generic "
                f"terms' sparse fit on {channel} is one fit, whichever disagreement on the channel it is set against.*",
                ""]
    shown.add(path)
    return [f"![{label}: residual against its fitted contribution]({path})", "",
            f"*{label}: its fitted contribution against the residual of {channel}, before (everything else found "
            "removed: along the dashed line when it explains it) and after (what is left); grey: ± the channel's "
            "noise floor.*", ""]


def world_lines(world: Mapping[str, Mapping[str, Any]], findings: Sequence[dict[str, Any]]) -> list[str]:
    """The world's effects beside the verdicts (simulated data: nature is known to the judge,
    never to discovery): each effect on, its strength, the library entries that describe it and
    what discovery said of them; then every named or ambiguous entry that describes none of them
    (a false name). ``world``: effect -> ``{"strength", "described_by"}``; ``findings``:
    ``result.json``'s."""
    said: dict[str, str] = {}
    for f in findings:
        for n in ([f["name"]] if f["name"] else []) + list(f["alternatives"]):
            said.setdefault(n, f["verdict"])
    L = ["## The world's effects beside the verdicts", "",
         "The simulated world's effects (nature, which discovery never sees) and what discovery said of the library "
         "entries that describe each; an effect of time (a new realisation every flight) is described by no entry.", "",
         "| effect of the world | strength | described by | what discovery said |", "|---|---|---|---|"]
    for name, w in world.items():
        by = list(w["described_by"])
        told = [f"`{n}` {said[n]}" for n in by if n in said]
        L.append(f"| `{name}` | {w['strength']:g} | {', '.join(f'`{n}`' for n in by) or '(no entry: an effect of time)'} "
                 f"| {'; '.join(told) or 'no entry of it named'} |")
    described = {n for w in world.values() for n in w["described_by"]}
    false = sorted(n for n, v in said.items() if v in ("named", "ambiguous") and n not in described)
    L += ["", ("**Named or ambiguous and in no effect of the world**: " + ", ".join(f"`{n}`" for n in false)
               if false else "Every entry named or offered as ambiguous describes an effect of the world."), ""]
    return L


def write_report(result: DiscoveryResult, out: Path, *, nominal: str = "as given to discovery",
                 references: dict[str, Any] | None = None, world: Mapping[str, Mapping[str, Any]] | None = None) -> None:
    """``report.md``, ``result.json``, ``verdicts.md`` (for the rerun recordings) and ``figures/`` in
    ``out``; ``nominal`` says where the nominal model's k_F and k_M come from; ``references``:
    label -> scores of other models on the same test flights (the benchmark's physics model);
    ``world`` (simulated data): the world's effects, set beside the verdicts (:func:`world_lines`)."""
    out = Path(out)
    a = result.analysis
    figs = out / "figures"
    rows = {"nominal (physics_full)": result.before, f"discovered ({result.name})": result.after}
    references = dict(references or {})
    if result.held_rate is not None:
        references.setdefault("physics (the nominal vehicle, dω/dt = 0: the paper's)", result.held_rate)
    rows.update(references)
    if result.sindy is not None and result.sindy["scores"] is not None:
        rows["plain SINDy (generic terms, no names)"] = result.sindy["scores"]
    if result.limit is not None:
        rows["state limit (true dynamics of the state)"] = result.limit
    if result.held_limit is not None:
        rows["state limit, ω held (true dynamics of the state, dω/dt = 0)"] = result.held_limit
    if result.oracle is not None:
        rows["oracle"] = result.oracle
    mae_horizon_figure(rows, figs / "mae_horizon.png", emphasis=[n for n in rows if n.startswith("discovered")])
    if a:
        channel_figure(a, figs / "channels.png")
    scatter = a.get("scatter", {}) if a else {}
    fig_of, shown = {}, set()
    for i, (label, d) in enumerate(scatter.items(), 1):
        fig_of[label] = f"figures/finding_{i}.png"
        finding_figure(label, d, out / fig_of[label])

    L: list[str] = ["# Model-discrepancy discovery", ""]
    counts = {v: sum(f.verdict == v for f in result.findings) for v in VERDICTS}
    L += [f"The nominal model (rigid body with the torque equation, k_F and k_M {nominal}) "
          f"was compared with the measurements. {len(result.findings)} disagreements stand above the noise floor: "
          + ", ".join(f"{n} {v}" for v, n in counts.items() if n or v == "named") + ". The augmented model "
          f"`{result.name}` is scored below against the nominal model"
          + (" and the oracle (the simulator's true dynamics)." if result.oracle else "."), ""]
    L += ["| SimErr on the test flights | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |",
          "|---|" + "---|" * len(QUANTITIES)]
    for label, sc in rows.items():
        L.append(f"| {label} | " + " | ".join(_fmt(sc.simerr[k]) for k in QUANTITIES) + " |")
    best = result.best_nominal
    L.append("| best nominal row (the lower of physics_full and physics, per quantity) | "
             + " | ".join(_fmt(best[k]) for k in QUANTITIES) + " |")
    L.append("| discovered against the best nominal row | "
             + " | ".join(f"{100 * (result.after.simerr[k] / best[k] - 1):+.1f} %" for k in QUANTITIES) + " |")
    for reference, label in (("limit", "state-limit"), ("held_limit", "(state limit, ω held)"), ("oracle", "oracle")):
        if getattr(result, reference) is not None:
            shares = gap_closed(result, reference)
            L.append(f"| share of the nominal–{label} gap closed | "
                     + " | ".join("–" if shares[k] is None else f"{100 * shares[k]:.0f} %" for k in QUANTITIES) + " |")
    if result.limit is not None or result.oracle is not None:
        L += ["", "The state limit is the simulator's true dynamics integrated without the effects that are not "
              "functions of the state (the turbulence and the rotors' thrust fluctuation, new in every flight): what "
              "a model that integrates the rotational dynamics reaches with every effect of the state known. It is "
              "no bound on other models: physics holds ω instead and, without those disturbances to integrate, "
              "can do better over the benchmark's half second, as the learned models can. The oracle also replays "
              "each test flight's realisation of those disturbances, which no model can know."]
    if result.held_limit is not None:
        L += ["", "The state limit with ω held is the same true dynamics of the state with the angular velocity held "
              "(dω/dt = 0), the paper's physics model's base: what a model on that base reaches with every effect of "
              "the state known as nature has them. It is no strict bound either: forces made wrong can offset part "
              "of what holding ω costs (a larger drag slows the drift of a velocity steered by a stale attitude)."]
    if result.oracle is not None:
        L += ["", "The shares of the gap closed are measured from the best nominal row, per quantity, to the oracle."]
    L += ["", f"![MAE against horizon: {horizon_caption(rows)}](figures/mae_horizon.png)", "",
          "*MAE against the prediction horizon on the test flights (log scale).*", ""]
    L += _per_flight(result)
    L += base_text(result.base)

    if world:
        L += world_lines(world, [_finding_dict(f) for f in result.findings])
    L += ["## Verdicts", ""]
    if not result.findings:
        L += ["No disagreement stands above the noise floor: the nominal model explains the measurements as well as "
              "the noise lets anything do.", ""]
    for f in result.findings:
        L += [_verdict_line(f), ""]
        if f.params:
            if f.entry is None:
                L += ["| generic term (`~`: centred and scaled) | coefficient |", "|---|---|"]
                L += [f"| {k} | {v:.4g} |" for k, v in f.params.items()]
            else:
                desc = LIBRARY[f.entry].description
                flights = f.evidence.get("ci_flights")
                L += [f"*{desc}*", "", "| coefficient | value | 95 % interval |"
                      + (" from flights | without each flight |" if flights else ""),
                      "|---|---|---|" + ("---|---|" if flights else "")]
                for k, v in f.params.items():
                    lo, hi = f.evidence["ci"][k]
                    row = f"| {k} | {v:.4g} | {lo:.4g} … {hi:.4g} |"
                    if flights:
                        flo, fhi = flights[k]
                        rlo, rhi = f.evidence["fold_range"][k]
                        row += f" {flo:.4g} … {fhi:.4g} | {rlo:.4g} … {rhi:.4g} |"
                    L.append(row)
            L.append("")
        label = f.entry or f"{f.verdict} ({', '.join(f.channels)})"
        if label in fig_of:
            L += figure_lines(label, fig_of[label], scatter[label]["channel"], shown)
    for d in result.dropped:
        h = d["history"]
        if h.get("implausible"):
            L += [f"**`{d['entry']}` chosen, then dropped**: not physically possible as the model would hold it "
                  f"(fitted on every flight at once, beside every entry chosen): {h['implausible']}. The selection "
                  "had judged the mean of its folds' fits.", ""]
        elif not h.get("holds", True):
            iv = (f"With the partner run's columns as the instrument, the slope of the residual on its contribution is "
                  f"{h['slope']:.2f} (95 % interval {h['ci'][0]:.2f} … {h['ci'][1]:.2f}; 1 for a real effect)")
            if h.get("whole") is False and h["ci"][1] >= 0.5 and h["slope"] <= AGREE:
                L += [f"**`{d['entry']}` chosen, then dropped**: only part of its fit repeats with the reference. "
                      f"{iv}, short of the {HISTORY_REPEAT:g} a lag of the rotors' wrench reaches (it repeats whole): "
                      "what it fitted beyond is the recorded rotor speeds' own noise, a few milliseconds of their "
                      "residual delay or the controller's answer to a disturbance, none of them a slow actuation.", ""]
            elif h["slope"] > AGREE:
                L += [f"**`{d['entry']}` chosen, then dropped**: least squares fitted less than what repeats with the "
                      f"reference. {iv}: its columns also carry the controller's answer to a disturbance, and its "
                      "coefficient is not the effect's.", ""]
            else:
                L += [f"**`{d['entry']}` chosen, then dropped**: its fit does not repeat with the reference. {iv}: "
                      "what it fitted is the controller's answer to a disturbance of the flight's own time, which "
                      "moves the signals it is made of.", ""]
        else:
            b = h["beyond_state"]
            L += [f"**`{d['entry']}` chosen, then dropped**: added to every state entry of the library fitted at "
                  f"once, it improves the held-out fit by {b['size']:.2f} noise floors (p = {b['p']:.2g}), short of "
                  "the selection's test: what it fitted, a function of the state fits as well (a rotor's inertia "
                  "answers the rotor speeds' rates as a short lag does).", ""]
    L += [_inertia_z_text(result), ""]
    if result.k_m.get("held"):
        searched = ("" if result.k_m.get("searched_with") != "least squares" else
                    " The search judged each candidate with k_F and k_M refitted alongside it by least squares, so "
                    "that a candidate is credited with what it adds; no coefficient of the model comes from that fit.")
        given = result.nominal.step.vehicle.k_f
        lagged = ("" if "slow_actuation" not in result.model.step.effects else
                  f" Beside the slow actuation, the rotors' own k_F in the augmented model is {result.vehicle.k_f:.4g}: "
                  "least squares of the thrust on the squares, the identify stage's fit, takes a lagging share's "
                  "fluctuations for a smaller k_F, and the shares are read against its value with that taken out.")
        L += [f"k_F and k_M are held at the identify stage's ({given:.4g} N s²/rad² and "
              f"{result.k_m['given']:.4g} N m s²/rad²) in the augmented model and in every coefficient fitted with "
              f"it; a least-squares refit of k_M on these closed-loop flights alongside what was found would give "
              f"{result.k_m['least_squares']:.4g} (the controller answers every yaw disturbance through the rotor "
              f"speeds it regresses on).{searched}{lagged}", ""]
    elif result.k_m:
        L += [f"k_M: the identify stage's {result.k_m['given']:.4g} N m s²/rad²; discovery refits it by least squares "
              f"alongside what it found, {result.k_m['least_squares']:.4g}, which the augmented model uses. On "
              "closed-loop flights least squares is biased where the controller answers a yaw disturbance through "
              "the rotor speeds; holding the identify stage's value instead keeps an effect that bends the yaw "
              "torque's relation to the rotor speeds (a lag of the rotors' wrench) from being named on simulated "
              "worlds that have one, because that value was estimated without it.", ""]
    if result.pairs:
        L += [f"Runs of one reference among the training flights (positions that agree time for time): {result.pairs}.",
              ""]
    if result.folds:
        L += [f"Every verdict was also sought without each training flight in turn ({len(result.folds)} folds); a "
              "named verdict must be reached on at least 80 % of them, and each coefficient's interval reaches its "
              "interval from flights (the folds' jackknife).", ""]
    if result.sindy is not None:
        L += [f"**Plain SINDy** (the same generic terms on the nominal residual, no names) keeps "
              f"{len(result.sindy['terms'])} terms" + ("; its rollouts diverge on the test flights." if result.sindy["diverged"]
                                                      else ".") , ""]

    if a and "spectra" in a:
        L += _observations(result, references, figs)
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
    summary["references"] = {label: sc.simerr for label, sc in (references or {}).items()}
    if world:
        summary["world"] = {k: dict(v) for k, v in world.items()}
    with atomic_file(out / "result.json") as tmp:
        tmp.write_text(json_text(summary))
    with atomic_file(out / "verdicts.md") as tmp:
        tmp.write_text(verdicts_markdown(summary["findings"]) + "\n")



def _touching(result: DiscoveryResult, channels: tuple[str, ...]) -> list:
    return [f for f in result.findings if set(f.channels) & set(channels)]


def _finding_phrase(f) -> str:
    ev = f.evidence
    if f.verdict == "unstable" and not f.entry:
        return (f"unstable on {', '.join(f.channels)}: would be {ev.get('was', 'unnamed')}, reached on "
                f"{ev['folds']['held']} of {ev['folds']['of']} flight folds")
    if f.verdict in ("named", "ambiguous", "unstable", "undetermined"):
        what = f"`{f.entry}`" if f.verdict != "ambiguous" else " or ".join(f"`{a}`" for a in f.alternatives)
        coef = "; ".join(f"{k} = {v:.3g} ({ev['ci'][k][0]:.3g} … {ev['ci'][k][1]:.3g})" for k, v in f.params.items())
        held = f", reached on {ev['folds']['held']} of {ev['folds']['of']} flight folds" if "folds" in ev else ""
        return f"{f.verdict} {what}{': ' + coef if coef else ''}{held}"
    if f.verdict == "unnamed" and ev.get("repeats"):
        src = ev["source"]
        return (f"unnamed on {', '.join(f.channels)}: {1e3 * ev['rms']:.3g} {_unit(f.channels[0])} RMS in {ev['band']} "
                f"that no entry or generic term of the state captures, and {100 * src['repeat_share']:.0f} % of it "
                f"repeats between runs of one reference (p = {src['p']:.2g}"
                + ("" if src.get("within_share") is None else
                   f"; {100 * src['within_share']:.0f} % with each flight's own mean removed")
                + "): a function of the reference (the input history or a state signal the library lacks), not of "
                "time")
    if f.verdict == "unnamed":
        return f"unnamed on {', '.join(f.channels)} (generic terms {', '.join(f.params)})"
    src = (ev.get("source") or {}).get("source", "undecided")
    return (f"not a function of the state on {', '.join(f.channels)}: {1e3 * ev['rms']:.3g} {_unit(f.channels[0])} RMS "
            f"in {ev['band']}, a function of {src}" if src != "undecided" else
            f"not a function of the state on {', '.join(f.channels)}: {1e3 * ev['rms']:.3g} {_unit(f.channels[0])} RMS "
            f"in {ev['band']}, its source undecided")


def _reference_text(h: dict[str, Any]) -> str:
    """An entry's checks against the reference (:func:`nanosysid.discover.select.check_reference`) in words."""
    out = []
    if h.get("checked"):
        out.append(f"instrumental slope {h['slope']:.2f}, 95 % {h['ci'][0]:.2f} … {h['ci'][1]:.2f}; a lag gives 1")
    b = h.get("beyond_state")
    if b:
        out.append(f"beyond every state entry: {b['size']:.2f} noise floors, p = {b['p']:.2g}")
    return "; ".join(out) or "not checked"


def _explained(a: dict[str, Any], c: int, part: str) -> float:
    b, f = a[f"rms_{part}"]["before"][c], a[f"rms_{part}"]["after"][c]
    return 1.0 - (f / b) ** 2 if b > 0 else 0.0


def _candidate_row(result: DiscoveryResult, name: str) -> dict[str, Any] | None:
    for candidates in reversed(result.rounds):
        for c in candidates:
            if c.name == name:
                return c.row()
    return None


def _flight_constant(result: DiscoveryResult, phys, figs: Path) -> list[str]:
    """How far the roll and pitch torque residual's mean moves from one training flight to the
    next, and what such a constant costs a model that integrates the torque over the horizon."""
    fm = result.analysis["flight_means"]
    if len(fm["flights"]) < 3:
        return []
    chs = ("tau_x", "tau_y")
    cols = [CHANNELS.index(ch) for ch in chs]
    before, low, high = (1e3 * v[cols] for v in spread(np.asarray(fm["before"])))
    after = 1e3 * spread(np.asarray(fm["after"]))[0][cols]
    flight_means_figure(result.analysis, list(chs), figs / "torque_xy_flights.png",
                        "each training flight's mean roll and pitch torque residual")
    text = (f"**A constant of each flight.** The mean of a flight's roll and pitch torque residual moves from one "
            f"flight to the next (the figure): over the {len(fm['flights'])} training flights its standard deviation "
            "is " + " and ".join(f"{_fmt(b)} mN·m for {ch} (95 % {_fmt(lo)} … {_fmt(hi)})"
                                 for ch, b, lo, hi in zip(chs, before, low, high))
            + f" with the nominal model, {_fmt(after[0])} and {_fmt(after[1])} with what was found. A model that "
            "starts each window from the state alone cannot know such a constant")
    if phys is not None:
        H = len(phys.mae["w"])
        turn = [1e-3 * b / result.vehicle.inertia[c - 3] * H * fm["dt"] for b, c in zip(before, cols)]
        text += (f": a torque of one standard deviation held over the horizon's {H} samples changes the angular "
                 f"velocity by {_fmt(turn[0])} rad/s ({chs[0]}) and {_fmt(turn[1])} rad/s ({chs[1]}) at h = {H}, "
                 f"where holding the rate (dω/dt = 0) is off by {_fmt(phys.mae['w'][-1])} rad/s (its mean absolute "
                 "error on the test flights)")
    text += "."
    # runs of one reference flown back to back share the flight's constant: through it alone a
    # residual repeats between them, which the test of a function of the reference counts
    partners = fm.get("partners") or []
    paired = [(i, j) for i, j in enumerate(partners) if j >= 0]
    if paired:
        m = np.asarray(fm["after"])
        left = np.asarray(result.analysis["rms_train"]["after"]) ** 2
        shared = [np.mean([m[i, c] * m[j, c] for i, j in paired]) / left[c] for c in cols]
        text += (" Runs of one reference share such a constant where they were flown back to back (the pairs "
                 "above): through their flights' constants alone, " + " and ".join(
                     f"{100 * sh:.0f} % ({ch})" for sh, ch in zip(shared, chs))
                 + " of the power left repeats between partner runs, which the test of a function of the "
                 "reference counts as repeating with the reference.")
    return [text, "", "![each flight's mean tau_x, tau_y residual](figures/torque_xy_flights.png)", "",
            "*Each training flight's mean roll and pitch torque residual, nominal model (red) and with what was "
            "found (green).*", ""]


def _observations(result: DiscoveryResult, references: dict[str, Any], figs: Path) -> list[str]:
    """The section answering the benchmark paper's three observations on its physical model."""
    a = result.analysis
    L = ["## The paper's three observations", "",
         "The paper (section \"Limitations of the physical model\") leaves three: body-frame forces in x and y the "
         "thrust model does not explain; a yaw torque the k_M model explains only in part; and in roll and pitch a "
         "low-frequency torque the quadratic model cannot account for, which it attributes, as a hypothesis, to "
         "slow actuation dynamics. Each is answered here from the training flights' residual (measured minus "
         "nominal wrench), with its spectrum before and after what was found.", ""]

    def explained_line(chs):
        return "; ".join(f"{ch}: {_fmt(1e3 * a['rms_train']['before'][CHANNELS.index(ch)])} → "
                         f"{_fmt(1e3 * a['rms_train']['after'][CHANNELS.index(ch)])} {_unit(ch)} RMS on the training "
                         f"flights ({100 * _explained(a, CHANNELS.index(ch), 'train'):.0f} % of its power explained; "
                         f"{100 * _explained(a, CHANNELS.index(ch), 'test'):.0f} % on the test flights)" for ch in chs)

    def findings_lines(chs):
        fs = _touching(result, chs)
        return [f"- {_finding_phrase(f)}" for f in fs] or ["- nothing above the noise floor"]

    # 1. x/y forces
    spectrum_figure(a, ["F_x", "F_y"], figs / "forces_xy.png", "body-frame force residual in x and y")
    L += ["### 1. The body-frame forces in x and y", "", explained_line(("F_x", "F_y")) + ".", "",
          "What discovery says of them:", "", *findings_lines(("F_x", "F_y")), "",
          "![F_x, F_y residual spectra](figures/forces_xy.png)", "",
          "*Power spectral density of the F_x and F_y residual on the training flights, nominal model (red) and "
          "with what was found (green).*", ""]
    # 2. yaw torque
    c = CHANNELS.index("tau_z")
    spectrum_figure(a, ["tau_z"], figs / "torque_z.png", "yaw torque residual")
    L += ["### 2. The yaw torque", "",
          f"The named effects explain {100 * _explained(a, c, 'train'):.0f} % of the yaw torque residual's power on "
          f"the training flights and {100 * _explained(a, c, 'test'):.0f} % on the test flights ({explained_line(('tau_z',))}).",
          "", *findings_lines(("tau_z",)), "",
          "![tau_z residual spectrum](figures/torque_z.png)", "", "*Power spectral density of the yaw torque residual.*", ""]
    # 3. low-frequency roll/pitch torque
    spectrum_figure(a, ["tau_x", "tau_y"], figs / "torque_xy.png", "roll and pitch torque residual")
    low = [i for i, (lo, hi) in enumerate(a["bands"]["edges"]) if lo == 0.0][0]
    band_rows = []
    for ch in ("tau_x", "tau_y"):
        k = CHANNELS.index(ch)
        tot_b = sum(a["bands"]["before"][i][k] for i in range(len(a["bands"]["edges"]))) or 1.0
        b, f = a["bands"]["before"][low][k], a["bands"]["after"][low][k]
        band_rows.append(f"| {ch} | {1e3 * b ** 0.5:.3g} | {100 * b / tot_b:.0f} % | {1e3 * f ** 0.5:.3g} | "
                         f"{100 * (1 - f / b) if b > 0 else 0:.0f} % |")
    L += ["### 3. The low-frequency roll and pitch torque", "",
          "| channel | below 1 Hz, nominal [mN·m RMS] | its share of the residual power | below 1 Hz, with what was "
          "found [mN·m RMS] | explained |", "|---|---|---|---|---|", *band_rows, "",
          "What it is a function of:", "", *findings_lines(("tau_x", "tau_y"))]
    slow = next((f for f in result.findings if f.entry == "slow_actuation"), None)
    dropped = next((d for d in result.dropped if d["entry"] == "slow_actuation"), None)
    row = _candidate_row(result, "slow_actuation")
    if slow is not None:
        h = slow.evidence.get("history") or {}
        L.append(f"- **the input history (slow actuation)**: `slow_actuation` is {slow.verdict}"
                 + (f" ({_reference_text(h)})" if h.get("checked") else "") + ".")
    elif dropped is not None:
        h = dropped["history"]
        why = (f"not physically possible as the model would hold it: {h['implausible']}"
               if h.get("implausible") else
               f"only part of its fit repeats with the reference (short of the {HISTORY_REPEAT:g} a lag reaches): the "
               "recorded rotor speeds' noise, their residual delay or the controller's answer to a disturbance"
               if h.get("whole") is False else
               "its instrumental and least-squares estimates disagree: the controller's answer to a disturbance "
               "moves its columns" if not h.get("holds", True) else
               "added to every state entry of the library at once, it no longer improves the held-out fit: it stood "
               "in for a function of the state")
        L.append(f"- **the input history (slow actuation)**: chosen, then dropped: {why} ({_reference_text(h)}).")
    elif row is not None:
        L.append(f"- **the input history (slow actuation)**: tried in every round, never eligible (last round: "
                 f"held-out gain {100 * row['heldout_gain']:.3f} %, p = {row['p']:.2g}).")
    bat = next((f for f in result.findings if f.entry == "battery_thrust"), None)
    brow = _candidate_row(result, "battery_thrust")
    if not a["predictable"].get("battery"):
        L.append("- **the battery**: no battery voltage recorded, not tested.")
    elif bat is not None:
        L.append(f"- **the battery**: `battery_thrust` is {bat.verdict}.")
    elif brow is not None:
        L.append(f"- **the battery**: `battery_thrust` tried in every round, never eligible (last round: held-out "
                 f"gain {100 * brow['heldout_gain']:.3f} %, p = {brow['p']:.2g}).")
    L += ["", "![tau_x, tau_y residual spectra](figures/torque_xy.png)", "",
          "*Power spectral density of the roll and pitch torque residual.*", ""]
    phys = next((sc for label, sc in references.items() if label.startswith("physics")), None)
    L += _flight_constant(result, phys, figs)
    pr = a["predictable"]
    L += ["**How much of what is left any function of the measured signals could predict** (the data's limit): a "
          "least-squares fit of the residual left by everything found, on the generic terms of the state, the rotor "
          "speeds' history (low-passes at " + ", ".join(f"{t:g}" for t in SLOW_TIMES) + " s) and the battery "
          "voltage's, scored held out on the folds of blocks. In closed loop the rotor speeds also carry the "
          "controller's answer to a disturbance, so this is an upper bound; what it cannot predict no model of "
          "these signals can.", "",
          "| channel | left [RMS] | predictable share (held out) | unpredictable [RMS] |", "|---|---|---|---|"]
    for k, ch in enumerate(CHANNELS):
        L.append(f"| {ch} | {1e3 * pr['power'][k]:.3g} {_unit(ch)} | {100 * pr['share'][k]:.1f} % | "
                 f"{1e3 * pr['power'][k] * (1 - pr['share'][k]) ** 0.5:.3g} {_unit(ch)} |")
    L.append("")
    decide = [f"`{n}`: {LIBRARY[n].excited_by}" for n in ("slow_actuation", "battery_thrust")]
    L += ["Flights that would decide what these flights cannot: " + "; ".join(decide) + ".", ""]
    lim = a.get("limit_simerr")
    if lim:
        L += ["**The data's limit in the benchmark**: the augmented model's rollouts on the test flights, its torque "
              "equation integrated about every axis (about a held axis no torque moves anything), given as "
              "a known extra wrench every part of the residual it leaves that the fit above predicts from the "
              "measured signals (fitted on the training flights): what the best model of those signals could reach.",
              "", "| SimErr on the test flights | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |",
              "|---|" + "---|" * len(QUANTITIES),
              f"| augmented | " + " | ".join(_fmt(result.after.simerr[k]) for k in QUANTITIES) + " |",
              f"| augmented, torque integrated about every axis, + the predictable rest (the data's limit) | " + " | ".join(_fmt(lim[k]) for k in QUANTITIES) + " |"]
        if phys is not None:
            L.append("| physics (dω/dt = 0) | " + " | ".join(_fmt(phys.simerr[k]) for k in QUANTITIES) + " |")
        L.append("")
    if phys is not None:
        better = {q: result.after.simerr[q] < phys.simerr[q] for q in ("R", "w")}
        L += ["### The rotational dynamics", "",
              f"The augmented model integrates the torque equation about "
              f"{', '.join(result.base.get('integrated', 'xyz')) or 'no body axis'} (chosen on the training flights: "
              f"the base section above); the paper's physics model holds the angular "
              f"velocity (dω/dt = 0). SimErr on the test flights, orientation and angular velocity: augmented "
              f"{_fmt(result.after.simerr['R'])} and {_fmt(result.after.simerr['w'])}, physics "
              f"{_fmt(phys.simerr['R'])} and {_fmt(phys.simerr['w'])}, nominal physics_full "
              f"{_fmt(result.before.simerr['R'])} and {_fmt(result.before.simerr['w'])}. "
              + ("The augmented model beats the paper's dω/dt = 0 in both: the rotational dynamics are back."
                 if all(better.values()) else
                 "The augmented model does not beat dω/dt = 0 in " + " and ".join(
                     {"R": "orientation", "w": "angular velocity"}[q] for q, b in better.items() if not b)
                 + (": even given every part of the torque residual the measured signals predict (the data's limit, "
                    f"{_fmt(lim['R'])} and {_fmt(lim['w'])}), the rollouts lose to holding the rate: what is left of "
                    "the torque is unpredictable from the measured signals, and integrated over a horizon it costs "
                    "more than dω/dt = 0 does." if lim and all(lim[q] >= phys.simerr[q] for q in ("R", "w")) else
                    (f": the data's limit ({_fmt(lim['R'])} and {_fmt(lim['w'])}) shows how much a model of the "
                     "measured signals could still gain." if lim else "."))), ""]
    return L


def _per_flight(result: DiscoveryResult) -> list[str]:
    """SimErr of the discovered model and the paper's physics model on each test flight."""
    phys = result.held_rate
    if phys is None or not result.after.per_flight or not phys.per_flight:
        return []
    L = ["**On each test flight**: SimErr of the discovered model against the paper's physics model (dω/dt = 0), "
         "and the relative difference.", "",
         "| test flight | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |", "|---|" + "---|" * len(QUANTITIES)]
    for name, sc in result.after.per_flight.items():
        ph = phys.per_flight[name].simerr
        L.append(f"| {name} | " + " | ".join(
            f"{_fmt(sc.simerr[k])} against {_fmt(ph[k])} ({100 * (sc.simerr[k] / ph[k] - 1):+.1f} %)" for k in QUANTITIES)
            + " |")
    return L + [""]


def base_text(base: dict[str, Any]) -> list[str]:
    """The section on the model's base (``result.json``'s ``base``): which axes integrate the
    torque equation and why, from the held-out rollouts of the training flights."""
    if not base:
        return []
    axes = base["integrated"]
    L = ["## The model's base, axis by axis", "",
         "The paper's physics model holds the angular velocity (dω/dt = 0): integrated, the rotors' torques drift "
         "from the measured rates within the horizon. The discovered model integrates the torque equation (with the "
         "named torque effects) about a body axis only where held-out rollouts of the training flights show it beats "
         "holding ω about that axis, in orientation and angular velocity both; about every other axis it holds ω, "
         "and the named force effects act whatever the axis. Generic terms join only where they worsen no quantity "
         "of those rollouts and improve one. No test flight enters any of these choices.", "",
         f"Held-out rollouts: {base['windows']} windows of the training flights (a start every {base['stride']} "
         f"samples, each inside one block of the selection's {base['folds']} folds), each rolled out by the model "
         "fitted without its fold. SimErr:", "",
         "| torque integrated about | generic terms | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |",
         "|---|---|" + "---|" * len(QUANTITIES)]
    for row in base["rows"]:
        L.append(f"| {', '.join(row['integrated']) or 'no axis (ω held)'} | {'with' if row['terms'] else 'without'} | "
                 + " | ".join(_fmt(row["simerr"][k]) for k in QUANTITIES) + " |")
    held = [a for a in "xyz" if a not in axes]
    L += ["", f"**Chosen**: " + (f"the torque equation about body {', '.join(axes)}" if axes else "no axis integrated")
          + (f"; ω held about {', '.join(held)}" if held else "")
          + ("; the generic terms joined." if base["terms_added"] else
             "; no generic term joined." if any(r["terms"] for r in base["rows"]) else "."), ""]
    return L


def headline(summary: dict[str, Any], report: str) -> list[str]:
    """The discovery report's headline (``result.json``'s ``summary``) for the README: the verdicts,
    the SimErr beside the nominal and reference models and the data's limit, and one line per
    observation of the paper; ``report`` is the report's path."""
    fs = summary["findings"]
    counts = {v: sum(f["verdict"] == v for f in fs) for v in VERDICTS}
    a = summary.get("analysis") or {}
    rows = [("nominal (physics_full)", summary["simerr"]["nominal"]),
            (f"discovered (`{summary['model']}`)", summary["simerr"]["discovered"]),
            *((label, sc) for label, sc in (summary.get("references") or {}).items())]
    if a.get("limit_simerr"):
        rows.append(("discovered, torque integrated about every axis, + what the measured signals predict (the "
                     "data's limit)", a["limit_simerr"]))
    L = [f"Discovery ([report]({report})): " + ", ".join(f"{n} {v}" for v, n in counts.items() if n) + ".", "",
         "| SimErr on the test flights | " + " | ".join(_QLABEL[k] for k in QUANTITIES) + " |",
         "|---|" + "---|" * len(QUANTITIES)]
    L += [f"| {label} | " + " | ".join(_fmt(sc[k]) for k in QUANTITIES) + " |" for label, sc in rows]
    base, best = summary.get("base"), summary["simerr"].get("best_nominal")
    if base and best:
        axes = base["integrated"]
        after = summary["simerr"]["discovered"]
        L += ["", "The base: " + (f"the torque equation integrated about body {', '.join(axes)}, ω held about the "
                                    "other axes" if axes else "ω held about every axis (dω/dt = 0, as the paper's "
                                    "physics model), the named force effects acting")
              + ", chosen on held-out rollouts of the training flights (the report's base section); against the best "
              "nominal row (the lower of physics_full and physics): "
              + ", ".join(f"{_QLABEL[k]} {100 * (after[k] / best[k] - 1):+.1f} %" for k in QUANTITIES) + "."]
    if a.get("rms_train"):
        def share(ch, part="test"):
            return f"{100 * _explained(a, CHANNELS.index(ch), part):.0f} %"

        low = [i for i, (lo, _) in enumerate(a["bands"]["edges"]) if lo == 0.0][0]

        def low_share(ch):
            c = CHANNELS.index(ch)
            b, f = a["bands"]["before"][low][c], a["bands"]["after"][low][c]
            return f"{100 * (1 - f / b) if b > 0 else 0:.0f} %"

        # the findings named on the x/y forces themselves, not those of other channels
        named = [f["name"] for f in fs if f["verdict"] == "named" and {"F_x", "F_y"} & set(f["channels"])]
        L += ["", f"- x/y forces: {share('F_x')} and {share('F_y')} of their residual power explained on the test "
              f"flights (named: {', '.join(f'`{n}`' for n in named) or 'none'});",
              f"- yaw torque: {share('tau_z')} of its residual power explained on the test flights;",
              f"- roll/pitch torque below 1 Hz: {low_share('tau_x')} and {low_share('tau_y')} of its power explained "
              "on the training flights; `slow_actuation` "
              + next((f["verdict"] for f in fs if (f["name"] or (f["alternatives"] or [None])[0]) == "slow_actuation"),
                     "not chosen") + ";"]
        fm = a.get("flight_means")
        if fm and len(fm["flights"]) >= 3:
            s, low, high = (1e3 * v for v in spread(np.asarray(fm["before"])))
            L.append(f"- a constant of each flight: the training flights' mean roll and pitch torque residual moves by "
                     + " and ".join(f"{_fmt(s[c])} mN·m (95 % {_fmt(low[c])} … {_fmt(high[c])})"
                                    for c in (CHANNELS.index("tau_x"), CHANNELS.index("tau_y")))
                     + f" from flight to flight (standard deviation over {len(fm['flights'])} flights).")
        else:
            L[-1] = L[-1][:-1] + "."
    return L


def _inertia_z_text(result: DiscoveryResult) -> str:
    """Whether the yaw inertia is identified, and the yaw coefficients as ratios to it where not."""
    jz = result.vehicle.inertia[2]
    f = next((f for f in result.findings if f.entry == "inertia"), None)
    ratios = [f"k_M / J_z = {result.vehicle.k_m / jz:.4g} s²/rad²"]
    gyro = next((g for g in result.findings if g.entry == "rotor_gyro"), None)
    if gyro is not None:
        ratios.append(f"J_r / J_z = {list(gyro.params.values())[0] / jz:.4g}")
    if f is None:
        return (f"**The yaw inertia J_z is not identified**: no inertia correction is named, so the model holds the "
                f"nominal {jz:.4g} kg m², and the yaw torques are known as ratios to it ({'; '.join(ratios)}).")
    k = LIBRARY["inertia"].params[2]
    lo, hi = f.evidence["ci"][k]
    j0 = jz - f.params[k]
    if "inertia_z_range" in f.evidence:
        a, b = f.evidence["inertia_z_range"]
        outside = "" if a <= jz <= b else f" The model's {jz:.4g} kg m² lies outside that range."
        return (f"**The yaw inertia J_z is not identified**: the flights tell the yaw torques' ratios to J_z, so its "
                f"interval spans the plausible range {a:.4g} … {b:.4g} kg m²; the model's yaw coefficients are "
                f"ratios to its {jz:.4g} kg m² ({'; '.join(ratios)}).{outside}")
    return f"The yaw inertia J_z is identified at {jz:.4g} kg m² (95 % interval {j0 + lo:.4g} … {j0 + hi:.4g})."
