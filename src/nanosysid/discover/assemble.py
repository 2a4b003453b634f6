"""Discovery's model assembly: the nominal vehicle refitted with the chosen corrections, the named
wrench entries and the generic terms as one augmented predictor, and the plain SINDy model for
comparison."""

from __future__ import annotations

import math
from typing import Any, Sequence

from nanosysid import protocol
from nanosysid.dataio import Flight
from nanosysid.discover import generic
from nanosysid.discover.model import AugmentedPredictor, AugmentedStep
from nanosysid.discover.records import Finding
from nanosysid.discover.search import Search
from nanosysid.effects import LIBRARY, NOMINAL, refitted_vehicle
from nanosysid.errors import PredictionError
from nanosysid.metrics import QUANTITIES
from nanosysid.vehicle import Vehicle

__all__ = ["assemble", "sindy_baseline"]


def assemble(vehicle: Vehicle, chosen: Sequence[str], coef: dict[str, list[float]], delay: float,
             terms: dict[str, float], findings: Sequence[Finding], train_flights: Sequence[Flight], *, horizon: int,
             batch_size: int) -> tuple[AugmentedPredictor, Vehicle]:
    """The augmented predictor and its vehicle: k_F, k_M and the chosen corrections refitted,
    the chosen wrench entries, the generic ``terms``, and the rotor speeds delayed by ``delay``
    s. Generic terms that make the training rollouts diverge, or worsen their SimErr in any
    quantity (a fit of one step on closed-loop flights need not help a rollout), are left out
    (their unnamed findings are marked ``added`` False)."""
    dk_f, dk_m = coef[NOMINAL.name]
    corrections = {n: LIBRARY[n].values(coef[n], vehicle) for n in chosen if LIBRARY[n].kind == "correction"}
    augmented_vehicle = refitted_vehicle(vehicle, dk_f, dk_m, corrections)
    named_wrench = [n for n in chosen if LIBRARY[n].kind == "wrench"]
    named_values = [x for n in named_wrench for x in coef[n]]
    model = AugmentedPredictor(AugmentedStep(augmented_vehicle, named_wrench + list(terms),
                                             named_values + list(terms.values())), delay=delay, name="discovered")
    if terms:
        without = AugmentedPredictor(AugmentedStep(augmented_vehicle, named_wrench, named_values), delay=delay,
                                     name="discovered")
        if _helps(model, without, train_flights, horizon, batch_size):
            return model, augmented_vehicle
        model = without
        for f in findings:
            if f.verdict == "unnamed":
                f.evidence["added"] = False
    return model, augmented_vehicle


def _helps(model: AugmentedPredictor, without: AugmentedPredictor, flights: Sequence[Flight], horizon: int,
           batch_size: int) -> bool:
    """Whether the model's rollouts stay finite over every window of ``flights`` and its SimErr
    is no worse than ``without``'s in any quantity."""
    try:
        with_terms = protocol.evaluate(model, flights, horizon=horizon, batch_size=batch_size).simerr
    except PredictionError:
        return False
    base = protocol.evaluate(without, flights, horizon=horizon, batch_size=batch_size).simerr
    return all(with_terms[q] <= base[q] for q in QUANTITIES)


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
