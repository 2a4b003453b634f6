"""Model-discrepancy discovery: where the nominal physics and the measurements disagree, which
named physical effect explains it, and the nominal model with that effect added.

Example::

    from nanosysid import discover
    result = discover.run(train_flights, test_flights)
    [(f.name, f.params) for f in result.found]     # the effects named, most important first
    result.before.simerr, result.after.simerr      # nominal and augmented model on test_flights
    result.model                                   # the augmented predictor (physics+<effects>)

The nominal model is ``physics_full`` (rigid body with the torque equation) with k_F and k_M
as the identify stage found them on the training flights (identified here when no vehicle is
given). The candidates are the library of :mod:`nanosysid.effects` (knowledge from the
literature); this package never imports the simulator's world. Effects are chosen by forward selection: each round, every
candidate not yet chosen is fitted together with those chosen, leaving one training flight out
at a time; the one that lowers the held-out residual most is named if that gain is at least
``threshold`` of the nominal residual and it helps on most held-out flights. The rounds stop
when no candidate clears the bar.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from nanosysid import benchmark
from nanosysid.dataio import Flight
from nanosysid.effects import CHANNELS, DELAY, LIBRARY, NOMINAL, Effect, split_coefficients
from nanosysid.errors import DataError
from nanosysid.discover.fit import Fitter, FlightData, flight_data, measured_wrench
from nanosysid.discover.model import AugmentedPredictor, AugmentedStep
from nanosysid.vehicle import Vehicle

__all__ = ["run", "Finding", "DiscoveryResult", "LIBRARY", "CHANNELS"]


@dataclass
class Finding:
    """A named effect with its fitted coefficients and the evidence for it.

    Attributes:
        name: The library effect's name.
        params: Coefficient name (with unit) -> fitted value, in the effect's parametrisation.
        evidence: ``explained_share`` (of the nominal residual's weighted sum of squares, on the
            training flights), ``heldout_gain`` (the same, held out: fitted without the flight
            it is measured on), ``folds_improved`` / ``folds``, ``stderr`` (jackknife over the
            training flights, per coefficient), ``round``.
    """

    name: str
    params: dict[str, float]
    evidence: dict[str, Any]

    @property
    def touches(self) -> tuple[str, ...]:
        return LIBRARY[self.name].touches


@dataclass
class DiscoveryResult:
    """What :func:`run` found, and the benchmark scores on the test flights."""

    found: list[Finding]
    before: benchmark.Scores
    after: benchmark.Scores
    model: AugmentedPredictor
    nominal: AugmentedPredictor
    vehicle: Vehicle
    rounds: list[list[dict[str, Any]]]
    threshold: float
    oracle: benchmark.Scores | None = None
    analysis: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return "+".join(["physics"] + [f.name for f in self.found])


class _Search:
    """Regression data per delay, built once and shared by every round."""

    def __init__(self, flights: Sequence[Flight], vehicle: Vehicle, window: int, order: int) -> None:
        self.flights, self.vehicle, self.window, self.order = list(flights), vehicle, window, order
        self.measured = [measured_wrench(f, vehicle, window, order) for f in self.flights]
        self._data: dict[float, list[FlightData]] = {}
        r0 = np.concatenate([d.r for d in self.data(0.0)])
        # channels in units of their own spread, so force (N) and torque (N m) weigh alike
        self.weights = 1.0 / np.maximum(r0.std(axis=0), 1e-12)
        self.total = Fitter(self.data(0.0), self.weights).nominal_sse()

    def data(self, delay: float) -> list[FlightData]:
        key = round(float(delay), 6)
        if key not in self._data:
            self._data[key] = [flight_data(f, self.vehicle, key, window=self.window, order=self.order, measured=m)
                               for f, m in zip(self.flights, self.measured)]
        return self._data[key]

    def fitter(self, delay: float) -> Fitter:
        return Fitter(self.data(delay), self.weights)


def _names(linear: list[str]) -> list[str]:
    return [NOMINAL.name] + linear


def _jackknife(thetas: np.ndarray) -> np.ndarray:
    n = len(thetas)
    return np.sqrt((n - 1) / n * ((thetas - thetas.mean(axis=0)) ** 2).sum(axis=0))


def _params(c: Effect, values: Sequence[float]) -> dict[str, float]:
    return {p: float(v) for p, v in zip(c.params, values)}


def run(train_flights: Sequence[Flight], test_flights: Sequence[Flight], *, vehicle: Vehicle | None = None,
        threshold: float = 0.005, delays: Sequence[float] = tuple(np.arange(1, 17) * 0.005), window: int = 15,
        order: int = 3, horizon: int = 50, oracle: Any = None, analysis: bool = True,
        batch_size: int = 8192) -> DiscoveryResult:
    """Find, name and add the effects the nominal model misses.

    Args:
        train_flights: Flights the effects are fitted on (and held out from, one at a time).
        test_flights: Flights the nominal and augmented models are scored on.
        vehicle: Nominal parameters, k_F and k_M as identified (the identify stage's
            ``params.json``, :func:`nanosysid.identify.load_params`); None: the paper's vehicle
            with k_F and k_M identified on ``train_flights``.
        threshold: Held-out gain (share of the nominal residual) an effect must reach.
        delays: Delays (s) searched for ``telemetry_delay``.
        window, order: Savitzky-Golay window and order of the derivatives and smoothing.
        horizon: Benchmark horizon.
        oracle: A predictor with the true dynamics (simulated data), scored for reference.
        analysis: Also compute where the models disagree (per channel, regime, band, rollout).
    """
    from nanosysid.identify import identify

    if len(train_flights) < 2:
        raise DataError(f"discover needs at least 2 training flights to hold each one out, got {len(train_flights)}")
    v = vehicle
    if v is None:
        thrust, yaw = identify(train_flights, Vehicle(), window=window, polyorder=order)
        v = dataclasses.replace(Vehicle(), k_f=thrust.coef, k_m=yaw.coef)
    search = _Search(train_flights, v, window, order)
    n = len(train_flights)
    need = math.ceil(2 * n / 3)

    linear: list[str] = []
    delay = 0.0
    current, _ = search.fitter(0.0).cv(_names(linear))
    found: list[Finding] = []
    rounds: list[list[dict[str, Any]]] = []
    while True:
        options = []
        for name, c in LIBRARY.items():
            if name in linear or c is DELAY:
                continue
            sse, thetas = search.fitter(delay).cv(_names(linear + [name]))
            options.append((name, delay, sse, thetas))
        if delay == 0.0:
            cv = {d: search.fitter(d).cv(_names(linear)) for d in delays}
            best = min(cv, key=lambda d: cv[d][0].sum())
            options.append((DELAY.name, best, cv[best][0], cv[best][1]))
        table = []
        for name, d, sse, _ in options:
            table.append({"candidate": name, "heldout_gain": float((current.sum() - sse.sum()) / search.total),
                          "folds_improved": int((sse < current).sum()), "folds": n,
                          **({"delay": float(d)} if name == DELAY.name else {})})
        table.sort(key=lambda r: -r["heldout_gain"])
        rounds.append(table)
        top = table[0] if table else None
        if top is None or top["heldout_gain"] < threshold or top["folds_improved"] < need:
            break
        name, d, sse, _ = next(o for o in options if o[0] == top["candidate"])
        if name == DELAY.name:
            delay = d
        else:
            linear.append(name)
        current = sse
        found.append(Finding(name, {}, {"round": len(rounds), "heldout_gain": top["heldout_gain"],
                                         "folds_improved": top["folds_improved"], "folds": n}))

    # final coefficients on every training flight, uncertainty by jackknife over the flights
    fitter = search.fitter(delay)
    names = _names(linear)
    theta = fitter.fit(names)
    _, thetas = fitter.cv(names)
    se = _jackknife(thetas)
    coef = {k: np.array(c) for k, c in split_coefficients(names, theta).items()}
    errs = split_coefficients(names, se)
    for f in found:
        c = LIBRARY[f.name]
        if c is DELAY:
            f.params = {DELAY.params[0]: delay}
            f.evidence["stderr"] = {DELAY.params[0]: _delay_stderr(search, linear, delays)}
        else:
            f.params = _params(c, coef[f.name])
            f.evidence["stderr"] = _params(c, errs[f.name])
    _explained_shares(search, found, delay)

    dk_f, dk_m = coef[NOMINAL.name]
    augmented_vehicle = dataclasses.replace(v, k_f=v.k_f + dk_f, k_m=v.k_m + dk_m)
    effects = [n for n in names if n != NOMINAL.name]
    step = AugmentedStep(augmented_vehicle, effects, np.concatenate([coef[n] for n in effects]) if effects else [])
    model = AugmentedPredictor(step, delay=delay, name="discovered")
    nominal = AugmentedPredictor(AugmentedStep(v), name="nominal")
    before = benchmark.evaluate(nominal, test_flights, horizon=horizon, batch_size=batch_size)
    after = benchmark.evaluate(model, test_flights, horizon=horizon, batch_size=batch_size)
    ref = benchmark.evaluate(oracle, test_flights, horizon=horizon, batch_size=batch_size) if oracle else None
    result = DiscoveryResult(found, before, after, model, nominal, augmented_vehicle, rounds, threshold, ref)
    if analysis:
        from nanosysid.discover.analysis import disagreement

        result.analysis = disagreement(result, search, names, theta, delay, test_flights, horizon=horizon,
                                       batch_size=batch_size)
    return result


def _delay_stderr(search: _Search, linear: list[str], delays: Sequence[float]) -> float:
    """Jackknife of the delay: refitted without each training flight in turn."""
    n = len(search.flights)
    sse = np.zeros((len(delays), n))  # in-sample SSE of each delay, on all flights but one
    for a, d in enumerate(delays):
        f = search.fitter(d)
        for i in range(n):
            rest = [j for j in range(n) if j != i]
            sse[a, i] = f.sse(_names(linear), f.fit(_names(linear), rest), rest)
    picks = np.asarray(delays)[sse.argmin(axis=0)]
    return float(_jackknife(picks[:, None])[0])


def _explained_shares(search: _Search, found: list[Finding], delay: float) -> None:
    """Each finding's share of the nominal residual, fitted on all training flights, adding
    the findings in the order they were named."""
    linear: list[str] = []
    d = 0.0
    f = search.fitter(d)
    prev = f.sse(_names(linear), f.fit(_names(linear)), range(len(search.flights)))
    for fd in found:
        if fd.name == DELAY.name:
            d = delay
        else:
            linear.append(fd.name)
        f = search.fitter(d)
        now = f.sse(_names(linear), f.fit(_names(linear)), range(len(search.flights)))
        fd.evidence["explained_share"] = float((prev - now) / search.total)
        prev = now
