"""The initialization-window track: the benchmark's windows with the samples before each start.

The paper's protocol gives a predictor the state ``y_t`` at a window's start and the rotor speeds
``u_{t..t+H-1}``. The field's loader for this dataset (nonlinear_benchmarks' NanoDrone) also gives
the ``W`` samples before the start, a state-initialization window. On this track a window starts
at ``t in {W, ..., T-H-1}``, so each flight gives ``T - H - W`` windows, not the paper's ``T - H``:
its scores stand apart from the paper's table.

A predictor with ``history = True`` is called as ``predict(y0, u, y_hist=, u_hist=)`` with
``y_hist (B, W, 13)`` and ``u_hist (B, W, 4)``, the samples ``t-W .. t-1`` (oldest first); any
other predictor is called as in the paper's protocol.

:func:`fit_rate_map` is the data's limit of the angular velocity on this track: per horizon step
and body axis, a least-squares map from what the window shows (the rates' and the nominal
torques' history) and the horizon's nominal torques to the change of the rate, fitted on the
training flights. It is linear in its features, so what it cannot predict held out, no linear
function of those signals can.

Example::

    from nanosysid import predictors, protocol, window
    bench = protocol.load("path/to/data")
    scores = window.evaluate(predictors.predictor("physics"), bench.test, horizon=50, init=50)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch

from nanosysid import metrics, so3
from nanosysid.dataio import SAMPLE_PERIOD, Flight
from nanosysid.errors import ConfigError, DataError
from nanosysid.numerics import LOOP_THREADS, threads
from nanosysid.protocol import Scores, check_flight, check_predictions

__all__ = ["windows", "evaluate", "orientation", "RateMap", "fit_rate_map", "held_out_rate_map", "references",
           "RATE_FEATURES"]

# the window's last samples the rate map reads (10 of the rates, every third of the torques) and
# every fifth of the horizon's torques: a few dozen features per step, fitted on ~10^5 windows
RATE_LAGS = 10
TORQUE_LAGS = (1, 4, 7, 10)
HORIZON_STRIDE = 5
RATE_FEATURES = ("the nominal torque equation's rate change over the horizon (the rotor speeds given)",
                 f"the rate's change over the window's last {RATE_LAGS} samples",
                 f"the nominal angular acceleration {', '.join(map(str, TORQUE_LAGS))} samples before the start",
                 f"the nominal angular acceleration at every {HORIZON_STRIDE}th sample of the horizon up to the step",
                 "a constant")


def _check(horizon: Any, init: Any) -> tuple[int, int]:
    for name, v, low in (("horizon", horizon, 1), ("init", init, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
            raise ConfigError(f"{name} must be a whole number >= {low}, got {v!r}")
    if init < RATE_LAGS:
        raise ConfigError(f"init must be at least {RATE_LAGS} samples (the rate map reads that many), got {init}")
    return int(horizon), int(init)


def windows(flight: Flight, horizon: int, init: int) -> dict[str, np.ndarray]:
    """The track's ``N = T - H - W`` windows of a flight, as strided views (no copy).

    Returns:
        ``start (N,)`` sample indices, ``y0 (N, 13)``, ``u (N, H, 4)``, the targets
        ``y (N, H, 13)``, and the window ``y_hist (N, W, 13)``, ``u_hist (N, W, 4)``.
    """
    horizon, init = _check(horizon, init)
    T = len(flight)
    n = T - horizon - init
    if n < 1:
        raise DataError(f"flight {flight.name}: {T} samples, fewer than init + horizon + 1 = {init + horizon + 1}")
    check_flight(flight)
    win = np.lib.stride_tricks.sliding_window_view
    start = np.arange(init, init + n)
    return {"start": start, "y0": flight.y[init:init + n],
            "u": win(flight.u[init:], horizon, axis=0)[:n].transpose(0, 2, 1),
            "y": win(flight.y[init + 1:], horizon, axis=0)[:n].transpose(0, 2, 1),
            "y_hist": win(flight.y, init, axis=0)[:n].transpose(0, 2, 1),
            "u_hist": win(flight.u, init, axis=0)[:n].transpose(0, 2, 1)}


def _read_only(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


def evaluate(predict: Callable[..., Any], flights: Sequence[Flight], *, horizon: int = 50, init: int = 50,
             batch_size: int = 8192) -> Scores:
    """Score ``predict`` on the track's windows of ``flights``: MAE per horizon over every
    window, and the same per flight (:attr:`Scores.per_flight`)."""
    horizon, init = _check(horizon, init)
    if not flights:
        raise DataError("no flights to score")
    history = bool(getattr(predict, "history", False))
    total = {k: np.zeros(horizon) for k in metrics.QUANTITIES}
    per_flight, count = {}, 0
    for flight in flights:
        w = windows(flight, horizon, init)
        n = len(w["start"])
        sums = {k: np.zeros(horizon) for k in metrics.QUANTITIES}
        for s in range(0, n, batch_size):
            b = slice(s, min(s + batch_size, n))
            extra = {"y_hist": _read_only(w["y_hist"][b]), "u_hist": _read_only(w["u_hist"][b])} if history else {}
            with threads(LOOP_THREADS):
                pred = predict(_read_only(w["y0"][b]), _read_only(w["u"][b]), **extra)
            pred = np.asarray(pred.detach().cpu().numpy() if hasattr(pred, "detach") else pred, dtype=np.float64)
            if pred.shape != (b.stop - b.start, horizon, 13):
                raise DataError(f"predictor returned shape {pred.shape} on flight {flight.name}; expected "
                                f"{(b.stop - b.start, horizon, 13)}")
            check_predictions(pred, f"flight {flight.name}")
            for k, e in metrics.errors(w["y"][b], pred).items():
                sums[k] += e.sum(axis=0)
        per_flight[flight.name] = Scores(mae={k: v / n for k, v in sums.items()}, n_windows=n)
        for k in total:
            total[k] += sums[k]
        count += n
    return Scores(mae={k: v / count for k, v in total.items()}, n_windows=count, per_flight=per_flight)


def _nominal_acceleration(u: np.ndarray, torque_map: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """The nominal angular acceleration ``(..., 3)`` in rad/s² of rotor speeds ``u (..., 4)``
    (rad/s): the mixer's body torques ``torque_map (3, 4) @ Ω²`` over the principal inertia
    ``(3,)`` (kg m²). The gyroscopic term ``ω × Jω`` is left out: it is a function of the rate,
    which the features carry."""
    return (u * u) @ torque_map.T / inertia


def _features(y0: np.ndarray, u: np.ndarray, y_hist: np.ndarray, u_hist: np.ndarray, torque_map: np.ndarray,
              inertia: np.ndarray):
    """Per horizon step ``k``, the design ``(N, 3, F)``: one row of features per window and axis
    (a generator over ``k``; the horizon's torques after step ``k`` are zero columns)."""
    dt = SAMPLE_PERIOD
    a_h = _nominal_acceleration(u, torque_map, inertia)  # (N, H, 3)
    a_w = _nominal_acceleration(u_hist, torque_map, inertia)  # (N, W, 3)
    w0 = y0[:, None, 10:13]
    rates = y_hist[:, -RATE_LAGS:, 10:13][:, ::-1] - w0  # (N, L, 3), newest first
    torques = a_w[:, [-j for j in TORQUE_LAGS]]  # (N, 4, 3)
    integral = np.cumsum(a_h, axis=1) * dt  # (N, H, 3)
    steps = np.arange(HORIZON_STRIDE, u.shape[1], HORIZON_STRIDE)
    ahead = a_h[:, steps]  # (N, S, 3); not the start's, which the integral of step 1 is already
    ones = np.ones((len(y0), 1, 3))
    for k in range(u.shape[1]):
        seen = ahead * (steps <= k)[None, :, None]
        yield np.concatenate((integral[:, k:k + 1], rates, torques, seen, ones), axis=1).transpose(0, 2, 1)


@dataclass
class RateMap:
    """The fitted map of :func:`fit_rate_map`, a predictor of the track (``history = True``).

    The rate along the horizon is ``ω_t + Φ_k c_{k,axis}``; the orientation is integrated from
    that rate (the midpoint of consecutive rates over each 10 ms step); position and velocity
    are those of ``base`` (any predictor of the paper's protocol), whose own orientation they
    follow.

    Attributes:
        coef: ``coef[k]`` of shape ``(3, F)``: each axis's coefficients at step ``k + 1``.
        torque_map: ``(3, 4)`` body torque per Ω², N m s²/rad².
        inertia: ``(3,)`` kg m².
        base: the predictor whose position and velocity are kept.
        ridge: the fit's ridge (:func:`_solve`).
        normal: each training flight's normal equations, by name (what :func:`held_out_rate_map`
            refits from).
    """

    coef: list[np.ndarray]
    torque_map: np.ndarray
    inertia: np.ndarray
    base: Callable[..., Any]
    ridge: float = 1e-6
    normal: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)
    history: bool = True

    def rates(self, y0, u, y_hist, u_hist) -> np.ndarray:
        """The predicted rates ``(B, H, 3)`` in rad/s."""
        phi = _features(np.asarray(y0), np.asarray(u), np.asarray(y_hist), np.asarray(u_hist), self.torque_map,
                        self.inertia)
        change = np.stack([np.einsum("naf,af->na", p, c) for p, c in zip(phi, self.coef)], axis=1)
        return np.asarray(y0)[:, None, 10:13] + change

    def __call__(self, y0, u, *, y_hist, u_hist) -> np.ndarray:
        pred = np.array(np.asarray(self.base(y0, u)), dtype=np.float64)
        w = self.rates(y0, u, y_hist, u_hist)
        pred[..., 10:13] = w
        pred[..., 6:10] = orientation(np.asarray(y0)[:, 6:10], np.asarray(y0)[:, 10:13], w)
        return pred


def orientation(q0: np.ndarray, w0: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Quaternions ``(B, H, 4)`` (xyzw) along body rates ``w (B, H, 3)`` from ``q0 (B, 4)`` with
    rate ``w0 (B, 3)`` at the start: each 10 ms step turns by the mean of its two end rates."""
    q = torch.from_numpy(np.ascontiguousarray(q0, dtype=np.float64))
    rates = torch.from_numpy(np.concatenate([np.asarray(w0)[:, None], w], axis=1))
    mid = 0.5 * (rates[:, 1:] + rates[:, :-1]) * SAMPLE_PERIOD
    out = []
    for k in range(mid.shape[1]):
        q = so3.quat_normalize(so3.quat_mul(q, so3.quat_exp(mid[:, k])))
        out.append(q)
    return torch.stack(out, dim=1).numpy()


def _normal_equations(flight: Flight, horizon: int, init: int, torque_map: np.ndarray,
                      inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A flight's share of the rate map's least squares: ``G (H, 3, F, F)`` and ``b (H, 3, F)``."""
    w = windows(flight, horizon, init)
    target = w["y"][..., 10:13] - w["y0"][:, None, 10:13]  # (N, H, 3)
    G, b = [], []
    for k, phi in enumerate(_features(w["y0"], w["u"], w["y_hist"], w["u_hist"], torque_map, inertia)):
        A = phi.transpose(1, 0, 2)  # (3, N, F)
        G.append(A.transpose(0, 2, 1) @ A)
        b.append((A.transpose(0, 2, 1) @ target[:, k].T[..., None])[..., 0])
    return np.stack(G), np.stack(b)


def _solve(G: np.ndarray, b: np.ndarray, ridge: float) -> list[np.ndarray]:
    """Coefficients ``(3, F)`` per step from summed normal equations, each feature's diagonal
    raised by ``ridge`` times itself: scale-free (the features' units differ by orders of
    magnitude), it only keeps near-collinear lags from a singular solve. A zero column (the
    horizon's torques after the step) gets a unit diagonal and a zero coefficient."""
    d = np.einsum("...ff->...f", G)
    d = np.where(d > 0, d, 1.0 / max(ridge, 1e-300))
    G = G + ridge * d[..., None] * np.eye(G.shape[-1])
    return list(np.linalg.solve(G, b[..., None])[..., 0])


def fit_rate_map(train: Sequence[Flight], *, base: Callable[..., Any], torque_map: np.ndarray,
                 inertia: np.ndarray, horizon: int = 50, init: int = 50, ridge: float = 1e-6) -> RateMap:
    """Fit the rate map on ``train``: per step and axis, ridge-regularised least squares."""
    horizon, init = _check(horizon, init)
    torque_map = np.asarray(torque_map, dtype=np.float64)
    inertia = np.asarray(inertia, dtype=np.float64)
    normal = {f.name: _normal_equations(f, horizon, init, torque_map, inertia) for f in train}
    G, b = sum(p[0] for p in normal.values()), sum(p[1] for p in normal.values())
    return RateMap(coef=_solve(G, b, ridge), torque_map=torque_map, inertia=inertia, base=base, ridge=ridge,
                   normal=normal)


def _reference(name: str) -> str:
    # flights are named <trajectory>_<date>_run<k>: the runs of one reference share the first part
    return name.split("_")[0]


def references(flights: Sequence[Flight]) -> int:
    """How many reference trajectories ``flights`` fly (the first part of their names)."""
    return len({_reference(f.name) for f in flights})


def held_out_rate_map(fit: RateMap, train: Sequence[Flight], *, horizon: int = 50, init: int = 50,
                      batch_size: int = 8192) -> Scores:
    """The rate map of ``fit`` scored on its training flights, the flights of each reference
    trajectory by the map refitted without them: what it reaches on a manoeuvre it was not fitted
    on, as on a test flight, before any test flight is looked at (runs of one reference repeat each
    other, so leaving out a single run would leave its twin in the fit)."""
    horizon, init = _check(horizon, init)
    if {f.name for f in train} != set(fit.normal):
        raise DataError("held_out_rate_map: the flights are not the ones the map was fitted on")
    groups = sorted({_reference(f.name) for f in train})
    if len(groups) < 2:
        raise DataError("the held-out rate map needs the flights of at least two reference trajectories")
    G, b = sum(p[0] for p in fit.normal.values()), sum(p[1] for p in fit.normal.values())
    per_flight = {}
    for g in groups:
        out = [f for f in train if _reference(f.name) == g]
        Gg = G - sum(fit.normal[f.name][0] for f in out)
        bg = b - sum(fit.normal[f.name][1] for f in out)
        refit = RateMap(coef=_solve(Gg, bg, fit.ridge), torque_map=fit.torque_map, inertia=fit.inertia,
                        base=fit.base, ridge=fit.ridge)
        per_flight.update(evaluate(refit, out, horizon=horizon, init=init, batch_size=batch_size).per_flight)
    per_flight = {f.name: per_flight[f.name] for f in train}
    n = sum(s.n_windows for s in per_flight.values())
    mae = {k: sum(s.mae[k] * s.n_windows for s in per_flight.values()) / n for k in metrics.QUANTITIES}
    return Scores(mae=mae, n_windows=n, per_flight=per_flight)
