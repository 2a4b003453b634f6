"""The campaign's records: the summary as text, and one table row per world."""

from __future__ import annotations

from typing import Any, Sequence

import pandas as pd

from nanosysid.dataio import json_text

__all__ = ["summary_markdown", "worlds_table"]


def _pct(x) -> str:
    return "–" if x is None else f"{100 * x:.0f} %"


def _sindy_median(x) -> str:
    # a rollout that diverges on the test flight closes a gap of minus infinity: where that is
    # most worlds the median is no number
    if x == float("-inf"):
        return "none (its rollouts diverge on the test flight in more than half of the worlds)"
    return _pct(x)


def summary_markdown(summary: dict[str, Any], *, relevant: float) -> str:
    """The campaign's figures, readable: recall per effect and strength bin, precision, clean and
    out-of-library worlds, gap closed, and the plain SINDy model beside."""
    L = ["# Discovery over hidden worlds", "",
         f"{summary['worlds']} worlds, {summary['failed']} where the augmented model diverged on the test flight.", "",
         f"Recall: worlds where a library entry that describes the effect is named or among an ambiguous "
         f"verdict's alternatives, among the worlds where the effect moves the nominal model's SimErr by more than "
         f"{100 * relevant:.0f} % (in brackets: among all worlds with the effect).", "",
         "| effect | " + " | ".join(f"strength {lo:g}–{hi:g}" for lo, hi in summary["strength_bins"]) + " |",
         "|---|" + "---|" * len(summary["strength_bins"])]
    for e, bins in sorted(summary["recall_counts"].items()):
        cells = []
        for lo, hi in summary["strength_bins"]:
            c = bins.get(f"{lo:g}-{hi:g}")
            cells.append("–" if c is None else f"{c['hit_relevant']}/{c['relevant']} ({c['hit']}/{c['worlds']})")
        L.append(f"| {e} | " + " | ".join(cells) + " |")
    L += ["",
          f"- named verdicts: {summary['named']}, right {_pct(summary['precision'])}",
          f"- clean worlds: {summary['clean_worlds']}, without any finding {_pct(summary['clean_without_finding'])}",
          f"- worlds with an effect outside the library: {summary['out_of_library_worlds']}, without a false name "
          f"{_pct(summary['out_of_library_without_false_name'])}",
          f"- worlds with an effect of the state: {summary['state_worlds']}, at least half the gap closed in "
          f"{_pct(summary['half_gap_closed'])} (median {_pct(summary['gap_closed_median'])})",
          f"- plain SINDy: median gap closed {_sindy_median(summary['sindy_gap_closed_median'])}, "
          f"{summary['sindy_terms_mean']:.1f} terms on average; discovery closes more of the gap in "
          f"{_pct(summary['beats_sindy'])} of the worlds",
          f"- named coefficients whose entry describes a world effect one to one: {summary['coefficients_checked']}, "
          f"their 95 % interval covering the world's truth in {_pct(summary['coefficients_covered'])}", ""]
    idn = summary.get("identify") or {}
    if idn:
        def q(d, scale, unit):
            return "–" if not d else (f"median {scale * d['median']:.3g} {unit}, 90 % {scale * d['p90']:.3g} {unit}, "
                                      f"95 % {scale * d['p95']:.3g} {unit}")

        L += ["## Identification over the worlds", "",
              "The sync step's motor lag (the setpoints as instruments over the world's flights, one session) and the identify "
              "step (k_F by least squares on the training flights; k_M by instrumental variables on a yaw calibration "
              "flight) on each world's flights, against its truth. k_M counts as identifiable where the world's inertia "
              "is the nominal one.", "",
              f"- motor lag: within {1e3 * idn['lag_tolerance']:g} ms in {_pct(idn['lag_within'])} of "
              f"{idn['worlds']} worlds; interval covers the truth in {_pct(idn['lag_covered'])}; "
              f"absolute error {q(idn['lag_abs_error'], 1e3, 'ms')}",
              f"- k_F: within {100 * idn['k_f_tolerance']:g} % in {_pct(idn['k_f_within'])}; interval covers nature's "
              f"thrust per sum of squared rotor speeds in {_pct(idn['k_f_covered'])}; absolute error "
              f"{q(idn['k_f_abs_error'], 100, '%')}",
              f"- k_M: within {100 * idn['k_m_tolerance']:g} % in {_pct(idn['k_m_within'])} of the "
              f"{idn['k_m_identifiable_worlds']} worlds that leave it identifiable; interval covers the truth in "
              f"{_pct(idn['k_m_covered'])} of all {idn['k_m_worlds']} with the yaw inertia anywhere in the sources' range "
              f"(in {_pct(idn.get('k_m_covered_given_inertia'))} with the vehicle's taken as exact); absolute error "
              f"{q(idn['k_m_abs_error'], 100, '%')}",
              f"- k_M by the paper's least squares on the training flights: absolute error "
              f"{q(idn['k_m_paper_abs_error'], 100, '%')}", ""]
    fam = summary.get("families") or {}
    if fam:
        L += ["## A function of the state, of the input history, or of time", "",
              "Worlds of one kind each, every training trajectory flown twice (runs of one reference to compare): a "
              "slow lag of the rotors' wrench alone (`thrust_lag`, which `slow_actuation` describes), turbulence "
              "alone (a function of time), gusts alone (a function of time of another shape and spectrum: steps), "
              "the recorded rotor speeds a few milliseconds late alone (`residual_delay`: what the sync stage "
              "leaves of the telemetry's delay), and state effects alone (the inertia, a torque scale, the drags, "
              "the rotor terms: never \"not a function of the state\"). Only the first may name `slow_actuation`. "
              "Counts of worlds; a world whose discovery "
              "failed is counted apart; where the augmented model's rollouts on the test flight diverge, its "
              "verdicts are counted and the divergence too.", "",
              "| family | worlds | failed | augmented model diverged | `slow_actuation` named | offered (named or "
              "ambiguous) | chosen, then dropped by its checks | with a finding \"not a function of the state\" | … called a function of time "
              "| a residual left unnamed that repeats with the reference | yaw inertia within 10 % | yaw inertia "
              "claimed identified (of them within 10 %) |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for name, d in fam.items():
            L.append(f"| {name} | {d['worlds']} | {d['failed']} | {d['diverged']} | {d['slow_actuation_named']} | "
                     f"{d['slow_actuation_offered']} | {d['slow_actuation_dropped']} | {d['stateless']} | "
                     f"{d['of_time']} | {d['repeats']} | {d['inertia_z_within']} | {d['inertia_z_claimed']} "
                     f"({d['inertia_z_claimed_within']}) |")
        L += ["", "Where the yaw inertia is not claimed identified, the discovery report says so: the flights tell "
              "the yaw torques' ratios to J_z, and the inertia correction's interval spans the plausible range.", ""]
    return "\n".join(L)


def _json_cell(value) -> str:
    """A table cell of strict JSON on one line (an unbounded interval's end is null)."""
    return json_text(value, indent=None, sort_keys=True).rstrip("\n")


def worlds_table(rows: Sequence[dict[str, Any]], effects: Sequence[str]) -> pd.DataFrame:
    """One row per world: its seed, each effect's strength (0: absent), the user effect, the
    verdicts, each effect's impact on the nominal SimErr, the gap closed and the SimErr of every
    model (nominal, discovered, oracle, sindy)."""
    out = []
    for r in rows:
        row: dict[str, Any] = {"world": r["world"], "seed": r["seed"]}
        row.update({f"strength_{e}": float(r["effects"].get(e, 0.0)) for e in effects})
        row["user"] = r["user"] or ""
        row["user_strength"] = float(r["user_strength"])
        row["error"] = r.get("error", "")
        for k in ("named", "ambiguous", "unnamed", "false_named"):
            row[k] = _json_cell(r.get(k, []))
        row["recalled"] = _json_cell(r.get("recalled", {}))
        row["coverage"] = _json_cell(r.get("coverage", []))
        row.update({f"impact_{e}": float(r.get("impact", {}).get(e, float("nan"))) for e in effects})
        for k in ("gap_closed", "sindy_gap_closed", "gap_share"):
            v = r.get(k)
            row[k] = float("nan") if v is None else float(v)
        row["sindy_terms"] = int(r.get("sindy_terms", 0))
        for k, v in r.get("identify", {}).items():
            row[f"identify_{k}"] = float("nan") if v is None else float(v)
        for model, scores in r.get("simerr", {}).items():
            row.update({f"simerr_{model}_{q}": float(v) for q, v in scores.items()})
        out.append(row)
    return pd.DataFrame(out)
