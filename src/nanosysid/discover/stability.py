"""Discovery without each training flight in turn: does every verdict and coefficient hold?

The blocks of one flight share its battery, its air and its estimator's drift; folds of blocks
cannot show what a whole flight does to a verdict. Here the whole search (selection, pruning,
the history check, the generic fit and the test of what is left) is run again without each
flight, and the chosen entries are fitted again without it: a verdict holds on a fold when the
fold reaches it too, and the coefficients' spread over the folds gives intervals from flights
(the delete-a-flight jackknife, Student's t for the flights' number).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from tqdm import tqdm

from nanosysid.discover.records import STATELESS, UNSTABLE, Finding
from nanosysid.discover.search import Search, true_torque_grams
from nanosysid.discover.select import Selection, check_reference, prune, select
from nanosysid.discover.sources import reference_pairs
from nanosysid.discover.stats import half_width, jackknife
from nanosysid.discover.verdicts import stateless, unnamed
from nanosysid.effects import DELAY, LIBRARY, NOMINAL, split_coefficients
from nanosysid.vehicle import Vehicle

__all__ = ["leave_one_flight_out", "apply", "HOLD"]

HOLD = 0.8  # share of the folds a verdict must hold on


def leave_one_flight_out(search: Search, selection: Selection, vehicle: Vehicle, delays: Sequence[float], *,
                         alpha: float, floor: float, share: float, progress: bool = False) -> list[dict[str, Any]]:
    """One row per training flight left out: the entries the fold chooses (``chosen``, and
    ``offered``: chosen or an ambiguous alternative), its delay, the channels of its unnamed
    and stateless findings, and the full selection's entries fitted without the flight
    (``coef``: entry -> physical values). Folds too short to judge are left out."""
    rows = []
    names = [NOMINAL.name, *selection.chosen]
    for k in tqdm(range(len(search.flights)), desc="discover: leave one flight out", disable=not progress):
        sub = search.without(k)
        if int(sub.blocks.max()) + 1 < 8:
            continue
        total = float(sub.grams(0.0).et.sum())
        sel = prune(sub, select(sub, delays, alpha=alpha, floor=floor, total=total), share)
        pairs = reference_pairs(sub.flights, [d.t for d in sub.data(0.0)])
        sel = check_reference(sub, sel, pairs, alpha=alpha, floor=floor)
        rest = unnamed(sub, sel, alpha=alpha, floor=floor, total=total)
        said = stateless(rest.left, sub, alpha, floor, total, pairs, sel.delay)
        left = [f for f in said if f.verdict == STATELESS]
        rest.findings += [f for f in said if f.verdict != STATELESS]
        offered = set(sel.chosen) | {a for pk in sel.picks for a in pk.alternatives}
        if sel.delay:
            offered.add(DELAY.name)
        cols = sub.cols(selection.chosen)
        g = true_torque_grams(sub, sub.fit_grams(selection.delay), selection.chosen, cols, vehicle)
        theta = split_coefficients(names, g.solve(cols))
        coef = {n: LIBRARY[n].values(theta[n], vehicle) for n in selection.chosen}
        rows.append({"flight": search.flights[k].name, "chosen": list(sel.chosen), "offered": sorted(offered),
                     "delay": float(sel.delay), "coef": coef,
                     "unnamed": [c for f in rest.findings for c in f.channels],
                     "stateless": [c for f in left for c in f.channels]})
    return rows


def _held(f: Finding, row: dict[str, Any]) -> bool:
    if f.verdict in ("named", "ambiguous"):
        if f.entry == DELAY.name:
            return row["delay"] > 0
        return bool({f.entry, *f.alternatives} & set(row["offered"]))
    key = "stateless" if f.verdict == STATELESS else "unnamed"
    return bool(set(f.channels) & set(row[key]))


def apply(findings: Sequence[Finding], rows: Sequence[dict[str, Any]], search: Search, selection: Selection,
          level: float = 0.95) -> None:
    """Each finding's fold stability into its evidence (``folds``: held on, out of, the
    flights whose fold does not reach it); a finding of any verdict that holds on fewer than
    :data:`HOLD` of the folds becomes ``unstable`` (``evidence["was"]``: the verdict it would
    have had): it rests on some of the flights, not on all. A named entry's interval is widened to
    reach its interval from flights (the folds' jackknife), kept as ``ci_flights``."""
    if not rows:
        return
    n = len(rows)
    for f in findings:
        held = [_held(f, r) for r in rows]
        ev = f.evidence
        ev["folds"] = {"held": int(sum(held)), "of": n, "missed": [r["flight"] for r, h in zip(rows, held) if not h]}
        name = f.entry
        if name in selection.chosen and f.verdict in ("named", "ambiguous"):
            params = LIBRARY[name].params
            values = np.array([r["coef"][name] for r in rows])
            se = jackknife(values)
            centre = np.array([f.params[p] for p in params])
            half = np.array([half_width(s, n, level) for s in se])
            ev["ci_flights"] = {p: (float(c - h), float(c + h)) for p, c, h in zip(params, centre, half)}
            ev["fold_range"] = {p: (float(values[:, i].min()), float(values[:, i].max())) for i, p in enumerate(params)}
            if "ci" in ev:
                ev["ci"] = {p: (min(ev["ci"][p][0], ev["ci_flights"][p][0]), max(ev["ci"][p][1], ev["ci_flights"][p][1]))
                            for p in params}
        if sum(held) < HOLD * n:
            ev["was"] = f.verdict
            f.verdict = UNSTABLE
