"""Discovery's model assembly: the nominal vehicle refitted with the chosen corrections, the named
wrench entries and the generic terms as one augmented predictor, its base (the torque equation
integrated or the angular velocity held, axis by axis) chosen on held-out rollouts of the
training flights, and the plain SINDy model for comparison."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

import numpy as np

from nanosysid import metrics, protocol
from nanosysid.dataio import Flight
from nanosysid.discover import generic
from nanosysid.discover.fit import EDGE
from nanosysid.discover.model import AugmentedPredictor, AugmentedStep, integrated_names
from nanosysid.discover.records import Finding
from nanosysid.discover.search import Search
from nanosysid.effects import LIBRARY, NOMINAL, lagged_k_f, refitted_vehicle
from nanosysid.errors import DataError, PredictionError
from nanosysid.metrics import QUANTITIES
from nanosysid.numerics import LOOP_THREADS, threads
from nanosysid.vehicle import Vehicle

__all__ = ["assemble", "heldout_windows", "heldout_simerr", "fold_terms", "sindy_baseline", "STRIDE"]


# Held-out rollouts start every STRIDE samples: neighbouring windows share all but one step, so
# a fifth of them tells the same story at a fifth of the cost
STRIDE = 5


def assemble(vehicle: Vehicle, chosen: Sequence[str], coef: dict[str, list[float]], delay: float,
             terms: dict[str, float], findings: Sequence[Finding], search: Search,
             per_fold: Sequence[dict[str, list[float]]], fits: Sequence[tuple[int, Any]], *, horizon: int,
             batch_size: int) -> tuple[AugmentedPredictor, Vehicle, dict[str, Any]]:
    """The augmented predictor, its vehicle and the evidence of its base: k_F, k_M and the chosen
    corrections refitted, the chosen wrench entries, the generic ``terms``, the rotor speeds
    delayed by ``delay`` s, and the torque equation integrated about the body axes where that
    beats holding the angular velocity.

    Every choice is made on held-out rollouts of the training flights (:func:`heldout_simerr`:
    windows inside one block, each rolled out by the model fitted without that block's fold):

    - **the base, axis by axis**: the paper's physics model holds the angular velocity
      (``dw/dt = 0``) because the rotors' torques, integrated, drift; an axis's torque (with the
      named torque effects) is integrated only where, integrated alone, it lowers the held-out
      SimErr of both the orientation and the angular velocity, and the axes so chosen together
      still do (else the one that gained least is held again);
    - **the generic terms** (``fits``: the unnamed findings' channels) join only where they
      make no quantity's held-out SimErr worse and lower at least one; each fold fits them on
      the other folds. Otherwise their unnamed findings are marked ``added`` False.
    """
    windows = heldout_windows(search, horizon, STRIDE)
    named_wrench = [n for n in chosen if LIBRARY[n].kind == "wrench"]

    def vehicle_of(c: dict[str, list[float]]) -> Vehicle:
        dk_f, dk_m = c[NOMINAL.name]
        corrections = {n: LIBRARY[n].values(c[n], vehicle) for n in chosen if LIBRARY[n].kind == "correction"}
        own = vehicle
        if "slow_actuation" in chosen:
            # the shares were fitted against the given k_F with what it took of the lag taken
            # out; the model's rotors carry k_F without it, in the thrust and the roll/pitch torques
            own = dataclasses.replace(vehicle, k_f=lagged_k_f(vehicle.k_f, c["slow_actuation"], search.lag_in_k_f))
        return refitted_vehicle(own, dk_f, dk_m, corrections)

    def model(c: dict[str, list[float]], integrated, extra: dict[str, float]) -> AugmentedPredictor:
        names = named_wrench + list(extra)
        values = [x for n in named_wrench for x in c[n]] + list(extra.values())
        return AugmentedPredictor(AugmentedStep(vehicle_of(c), names, values, integrated=integrated), delay=delay,
                                  name="discovered")

    def heldout(integrated, with_terms: bool = False) -> dict[str, float]:
        resid = search.residual(chosen, delay, model=True)[0] if with_terms else None
        models = [model(c, integrated, fold_terms(search, resid, delay, fits, k) if with_terms else {})
                  for k, c in enumerate(per_fold)]
        return heldout_simerr(models, search.flights, windows, horizon, batch_size)

    rows = []

    def tried(axes, with_terms: bool = False) -> dict[str, float]:
        rows.append({"integrated": integrated_names(axes), "terms": with_terms, "simerr": heldout(axes, with_terms)})
        return rows[-1]["simerr"]

    held = tried((False, False, False))
    gain = {}
    for a in range(3):
        s = tried(tuple(i == a for i in range(3)))
        if s["R"] < held["R"] and s["w"] < held["w"]:
            gain[a] = held["w"] - s["w"]
    picked = sorted(gain, key=gain.get, reverse=True)
    while len(picked) > 1:
        s = tried(tuple(i in picked for i in range(3)))
        if s["R"] < held["R"] and s["w"] < held["w"]:
            break
        picked.pop()  # the axis that gained least alone is held again
    integrated = tuple(i in picked for i in range(3))
    best = next(r["simerr"] for r in reversed(rows) if r["integrated"] == integrated_names(integrated))
    added = False
    if terms:
        s = tried(integrated, with_terms=True)
        added = all(s[q] <= best[q] for q in QUANTITIES) and any(s[q] < best[q] for q in QUANTITIES)
        if not added:
            for f in findings:
                if f.verdict == "unnamed":
                    f.evidence["added"] = False
    augmented_vehicle = vehicle_of(coef)
    result = model(coef, integrated, terms if added else {})
    evidence = {"integrated": integrated_names(integrated), "terms_added": added, "stride": STRIDE,
                "windows": int(sum(len(s) for per in windows for s in per)), "folds": len(per_fold), "rows": rows}
    return result, augmented_vehicle, evidence


def heldout_windows(search: Search, horizon: int, stride: int) -> list[list[np.ndarray]]:
    """The starts of the held-out windows of every training flight, per fold: every ``stride``-th
    window whose start and targets lie in one block of the regression (a window that reaches
    into a neighbouring block would be scored on samples its fold's model was fitted on)."""
    fold_of_block = search.grams(0.0).fold
    out, start = [], 0
    for f, d in zip(search.flights, search.data(0.0)):
        n = len(d.r)
        blocks = search.blocks[start:start + n]
        start += n
        s = np.arange(0, max(len(f) - horizon, 0), stride)
        first, last = s - EDGE, s + horizon - EDGE  # the window's first state and last target, as samples of d
        ok = (first >= 0) & (last < n)
        s, first, last = s[ok], first[ok], last[ok]
        inside = blocks[first] == blocks[last]
        s, fold = s[inside], fold_of_block[blocks[first[inside]]]
        out.append([s[fold == k] for k in range(search.folds)])
    return out


def heldout_simerr(models: Sequence[AugmentedPredictor], flights: Sequence[Flight], starts: Sequence[Sequence[np.ndarray]],
                   horizon: int, batch_size: int) -> dict[str, float]:
    """SimErr per quantity (the MAE summed over h = 1..horizon, pooled over windows) of
    ``models[k]`` rolled out from the starts ``starts[flight][k]`` of each flight; infinite where a
    rollout leaves the finite states or the unit quaternions.

    Each fold's windows of every flight are rolled out together, in batches of ``batch_size``: a
    rollout's cost is its steps' overhead far more than its windows."""
    per_flight = [protocol.windows(f, horizon) for f in flights]
    sums, n = {q: 0.0 for q in QUANTITIES}, 0
    for k, predict in enumerate(models):
        picked = [(w, s[k]) for w, s in zip(per_flight, starts) if len(s[k])]
        if not picked:
            continue
        y0, u, y = (np.concatenate([w[i][s] for w, s in picked]) for i in range(3))
        for b in range(0, len(y0), batch_size):
            part = slice(b, b + batch_size)
            with threads(LOOP_THREADS):
                pred = predict(y0[part], u[part])
            try:
                protocol.check_predictions(pred, f"fold {k}'s held-out windows")
            except PredictionError:
                return {q: math.inf for q in QUANTITIES}
            for q, e in metrics.errors(y[part], pred).items():
                sums[q] += float(e.sum())
            n += len(pred)
    if n == 0:
        raise DataError("discover: no window of the training flights lies inside one block; give longer flights "
                        "or a longer discover.block than the horizon")
    return {q: sums[q] / n for q in QUANTITIES}


def fold_terms(search: Search, resid: np.ndarray, delay: float, fits: Sequence[tuple[int, Any]],
               k: int) -> dict[str, float]:
    """The generic terms of the channels in ``fits`` fitted on the weighted residual ``resid
    (N, 6)`` without fold ``k``'s blocks, as raw library terms
    (:func:`nanosysid.discover.generic.terms_of`)."""
    if not fits:
        return {}
    lib, terms = search.terms(delay)
    rows = np.flatnonzero(search.grams(delay).fold[search.blocks] != k)
    out: dict[str, float] = {}
    for c, _ in fits:
        coef = generic.sparse_fit(terms[rows], resid[rows][:, [c]])
        out.update(generic.terms_of(coef, lib, [c], search.weights)[0])
    return out


def sindy_baseline(search: Search, vehicle: Vehicle, test_flights, horizon, batch_size) -> dict[str, Any]:
    """The plain SINDy discrepancy model: generic sparse terms on the nominal residual, no names."""
    resid, theta = search.residual([], 0.0)
    lib, terms = search.terms(0.0)
    coef = generic.sparse_fit(terms, resid)
    kept, shown = generic.terms_of(coef, lib, range(6), search.weights)
    dk_f, dk_m = theta
    step = AugmentedStep(refitted_vehicle(vehicle, dk_f, dk_m, {}), list(kept),
                         list(kept.values()))
    model = AugmentedPredictor(step, name="sindy")
    try:
        scores = protocol.evaluate(model, test_flights, horizon=horizon, batch_size=batch_size)
    except PredictionError:  # its rollouts diverge: the plain fit's own failure, recorded as such
        return {"terms": shown, "simerr": {q: math.inf for q in QUANTITIES}, "scores": None, "model": model,
                "diverged": True}
    return {"terms": shown, "simerr": scores.simerr, "scores": scores, "model": model, "diverged": False}
