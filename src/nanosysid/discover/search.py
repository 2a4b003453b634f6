"""Discovery's regression data: every training flight's measured wrench, regressors and noise
floor (:mod:`nanosysid.discover.fit`), cut into blocks and folds, with the normal equations per
rotor-speed delay built once and shared by every phase."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from nanosysid.dataio import Flight
from nanosysid.discover import generic
from nanosysid.discover.fit import (COLUMN_ENTRIES, EDGE, ChainFilter, FlightData, Grams, block_ids, flight_data,
                                    input_noise_draws, input_noise_grams, local_floor, measured_wrench, rotor_products)
from nanosysid.effects import CHANNELS, DELAY, INERTIA_SHARE, NOMINAL, entry, lag_in_k_f, split_coefficients
from nanosysid.errors import DataError
from nanosysid.vehicle import Vehicle

__all__ = ["Search", "true_torque_grams", "channels_of"]


class Search:
    """Regression data and block normal equations per delay, built once and shared by every round."""

    def __init__(self, flights: Sequence[Flight], vehicle: Vehicle, window: int, order: int, block: float,
                 folds: int, hold_k_m: bool = False, hold_nominal: bool = False,
                 chain: ChainFilter | None = None, noise_draws: int = 4, force_bias: bool = True) -> None:
        self.flights, self.vehicle, self.window, self.order = list(flights), vehicle, window, order
        # the filters the data chain ran the sensors through (the shape of their noise), and how
        # many draws of the rotor speeds' noise measure what it adds to the normal equations
        # (errors in variables; 0: left in)
        self.chain, self.noise_draws = chain or ChainFilter(), noise_draws
        self._noise_grams: Grams | None = None
        # the accelerometer's bias, new each flight: the force channels' flight means left out
        self.force_bias = force_bias
        # k_M as given (the identify stage's, by instrumental variables where it could): a least
        # squares refit on closed-loop flights brings back the bias that estimator removes
        self.hold_k_m = hold_k_m
        # k_F and k_M as given in the fits the model is made of (fit_grams), while the search
        # judges each candidate with them refitted alongside
        self.hold_nominal = hold_nominal
        self._fit_grams: dict[float, Grams] = {}
        self._parent: Search | None = None
        self._skip = -1
        # the given k_F is the identify stage's least squares on these flights: what it took of
        # a slow actuation's lag, taken out of that entry's columns
        self.lag_in_k_f = lag_in_k_f([f.u for f in self.flights], float(np.median(np.diff(self.flights[0].t))))
        self.measured = [measured_wrench(f, vehicle, window, order) for f in self.flights]
        local = [local_floor(f, vehicle, window, order, self.chain) for f in self.flights]
        self.noise_parts = np.sqrt(np.concatenate(local).mean(axis=0))
        self.noise = np.hypot(*self.noise_parts)
        self.weights = 1.0 / np.maximum(self.noise, 1e-12)
        self._data: dict[float, list[FlightData]] = {}
        self._grams: dict[float, Grams] = {}
        self._terms: dict[float, tuple[generic.TermLibrary, np.ndarray]] = {}
        dt = float(np.median(np.diff(self.flights[0].t)))
        self.blocks = block_ids(self.data(0.0), max(1, int(round(block / dt))))
        n_blocks = int(self.blocks.max()) + 1
        # each block's noise variance per channel, a share of the mean's: the rotors' vibration
        # makes a block of sharp corners several times noisier than one of a slow sweep, and
        # every fit and test weighs a block by its own noise
        var = np.concatenate([v[EDGE:-EDGE].sum(axis=1) for v in local])
        counts = np.bincount(self.blocks, minlength=n_blocks)
        self.block_noise = np.stack([np.bincount(self.blocks, weights=var[:, c], minlength=n_blocks)
                                     for c in range(6)], axis=1) / np.maximum(counts, 1)[:, None]
        self.block_noise /= np.maximum(self.noise ** 2, 1e-300)
        if n_blocks < 4:
            raise DataError(f"discover: the training flights make {n_blocks} blocks of {block:g} s; at least 4 are "
                            "needed to hold some out (give longer flights or a shorter discover.block)")
        self.folds = min(folds, n_blocks // 2)  # short data: fewer, larger folds
        self.offsets = {}
        k = 0
        for name in COLUMN_ENTRIES:
            P = entry(name).n_columns
            self.offsets[name] = np.arange(k, k + P)
            k += P

    def without(self, flight: int) -> "Search":
        """The same search without flight ``flight``'s samples (its blocks dropped, the rest
        dealt to the folds again), sharing this one's regression data and normal equations; the
        noise floor stays this one's."""
        sub = object.__new__(Search)
        sub.__dict__.update(self.__dict__)
        sub._parent, sub._skip = self, flight
        sub.flights = [f for i, f in enumerate(self.flights) if i != flight]
        sub.measured = [m for i, m in enumerate(self.measured) if i != flight]
        old = self.blocks[self.flight_index != flight]
        sub._blocks_kept = np.unique(old)
        sub.blocks = np.searchsorted(sub._blocks_kept, old)
        sub.folds = min(self.folds, len(sub._blocks_kept) // 2)
        sub.block_noise = self.block_noise[sub._blocks_kept]
        sub._data, sub._grams, sub._terms, sub._fit_grams, sub._noise_grams = {}, {}, {}, {}, None
        return sub

    @property
    def flight_index(self) -> np.ndarray:
        """Each regression sample's flight (its index in ``flights``), ``(N,)``."""
        return np.repeat(np.arange(len(self.flights)), [len(d.r) for d in self.data(0.0)])

    def data(self, delay: float) -> list[FlightData]:
        key = round(float(delay), 6)
        if self._parent is not None:
            return [d for i, d in enumerate(self._parent.data(key)) if i != self._skip]
        if key not in self._data:
            self._data[key] = [flight_data(f, self.vehicle, key, window=self.window, order=self.order, measured=m,
                                           force_bias=self.force_bias, lag_in_k_f=self.lag_in_k_f)
                               for f, m in zip(self.flights, self.measured)]
        return self._data[key]

    def grams(self, delay: float) -> Grams:
        key = round(float(delay), 6)
        if self._parent is not None and key not in self._grams:
            self._grams[key] = self._parent.grams(key).subset(self._blocks_kept, self.folds)
        if key not in self._grams:
            g = self._free_grams(key)
            self._grams[key] = g.fixed(int(self.offsets[NOMINAL.name][1]), 0.0) if self.hold_k_m else g
        return self._grams[key]

    def _free_grams(self, delay: float) -> Grams:
        """The normal equations of every column at ``delay``, the rotor speeds' noise taken out."""
        d = self.data(delay)
        X = np.concatenate([np.concatenate([fd.features[n] for n in COLUMN_ENTRIES], axis=-1) for fd in d])
        y = np.concatenate([fd.r for fd in d])
        g = Grams(X, y, self.weights, self.blocks, self.folds)
        g = g.minus(self.input_noise_grams()) if self.noise_draws else g
        return g.per_block(1.0 / np.maximum(self.block_noise, 1e-12))

    def input_noise_grams(self) -> Grams:
        """What the rotor speeds' noise adds to the normal equations (:func:`input_noise_grams`),
        measured once, at no delay: a shift of a few samples moves the columns' dependence on
        the speeds by less than the draws' own scatter."""
        if self._noise_grams is None:
            draws = [input_noise_draws(f, self.vehicle, 0.0, window=self.window, order=self.order,
                                       chain=self.chain, draws=self.noise_draws, seed=i, lag_in_k_f=self.lag_in_k_f)
                     for i, f in enumerate(self.flights)]
            self._noise_grams = input_noise_grams(draws, self.weights, self.blocks, self.folds)
        return self._noise_grams

    def fit_grams(self, delay: float) -> Grams:
        """The normal equations the model's coefficients are fitted with: :meth:`grams`, with k_F
        and k_M held at the given vehicle's where ``hold_nominal``."""
        if not self.hold_nominal:
            return self.grams(delay)
        key = round(float(delay), 6)
        if key not in self._fit_grams:
            g = self.grams(key)
            for col in self.offsets[NOMINAL.name]:
                if int(col) not in g.fixed_values:
                    g = g.fixed(int(col), 0.0)
            self._fit_grams[key] = g
        return self._fit_grams[key]

    def free_k_m(self, names: Sequence[str], delay: float) -> float:
        """The k_M correction a least-squares refit alongside ``names`` would make (N m s²/rad²),
        reported beside the one held."""
        return float(self._free_grams(delay).solve(self.cols(names))[1])

    def terms(self, delay: float) -> tuple[generic.TermLibrary, np.ndarray]:
        """The generic terms' library and their values on every sample ``(N, M)``."""
        key = round(float(delay), 6)
        if key not in self._terms:
            signals = np.concatenate([fd.terms for fd in self.data(key)])
            lib = generic.TermLibrary(signals)
            self._terms[key] = (lib, lib(signals))
        return self._terms[key]

    def rotor_products(self, delay: float) -> np.ndarray:
        """:func:`~nanosysid.discover.fit.rotor_products` on every sample ``(N, 21)``."""
        return np.concatenate([rotor_products(f, d.t, delay, window=self.window, order=self.order)
                               for f, d in zip(self.flights, self.data(delay))])

    def touched(self, name: str) -> set[int]:
        """The channels an entry's columns act on."""
        if name == DELAY.name:
            return set(range(6))
        f = self.data(0.0)[0].features[name]
        return set(np.flatnonzero(np.any(f != 0, axis=(0, 2))).tolist())

    def cols(self, names: Sequence[str]) -> np.ndarray:
        return np.concatenate([self.offsets[n] for n in [NOMINAL.name, *names]])

    def residual(self, names: Sequence[str], delay: float, *, model: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Weighted residual left by ``names`` fitted on every block ``(N, 6)``, and the
        coefficients; ``model``: fitted as the model's coefficients are (:meth:`fit_grams`)."""
        g = self.fit_grams(delay) if model else self.grams(delay)
        cols = self.cols(names)
        theta = g.solve(cols)
        d = self.data(delay)
        X = np.concatenate([np.concatenate([fd.features[n] for n in [NOMINAL.name, *names]], axis=-1) for fd in d])
        y = np.concatenate([fd.r for fd in d])
        return (y - X @ theta) * self.weights, theta

    def nested_delay(self, names: Sequence[str], delays: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """Held-out SSE per block with the delay chosen on the other folds, and each fold's delay."""
        cols = self.cols(names)
        fits = {d: self.grams(d) for d in delays}
        out, chosen = np.zeros(int(self.blocks.max()) + 1), np.zeros(self.folds)
        for k in range(self.folds):
            train = np.flatnonzero(fits[delays[0]].fold != k)
            test = np.flatnonzero(fits[delays[0]].fold == k)
            best, best_sse, best_theta = None, np.inf, None
            for d, g in fits.items():
                th = g.solve(cols, train)
                s = g.sse(cols, th, train).sum()
                if s < best_sse:
                    best, best_sse, best_theta = d, s, th
            chosen[k] = best
            out[test] = fits[best].sse(cols, best_theta, test)
        return out, chosen


def true_torque_grams(search: Search, g: Grams, chosen: Sequence[str], cols: np.ndarray, vehicle: Vehicle,
                       iterations: int = 8, yaw_inertia: float | None = None) -> Grams:
    """The normal equations in which every torque coefficient is in the true body's units.

    The measured torque is ``J dw/dt + w x Jw`` with the *nominal* J. Where the body's inertia
    is ``J + dJ``, every torque the rotors and the effects exert shows up in it shrunk by
    ``J / (J + dJ)`` per axis: a k_M refit or a rotor inertia fitted there is the true one
    times that ratio, and one rotor inertia cannot serve the roll/pitch gyroscopic torque and
    the yaw reaction at once when the ratios differ by axis. The augmented model integrates
    with ``J + dJ``, so the torque columns of every entry but the inertia correction itself are
    scaled by ``J / (J + dJ)`` and the fit is repeated with the ``dJ`` it finds (a fixed point,
    reached in a few rounds): the coefficients are then the true body's, one parametrisation
    for the fit and the model.

    ``yaw_inertia`` (kg m²) holds the body's yaw inertia ``J_z + dJ_z`` at that value instead of
    fitting it: the flights tell the yaw torques' ratios to J_z rather than J_z, so the fits at
    the ends of its plausible range show how far every yaw coefficient may move with it.
    """
    if "inertia" not in chosen:
        return g
    J = np.asarray(vehicle.inertia)
    own = np.concatenate([search.offsets[n] for n in [NOMINAL.name, *chosen] if n == "inertia"])
    base, held = g, None
    if yaw_inertia is not None:
        # the column coefficient c of dJ = c J / (J - c): c = J - J² / (J + dJ)
        held = J[2] / yaw_inertia
        base = g.fixed(int(own[2]), J[2] - J[2] * held)
    scale = np.ones((6, g.P))
    fitted = base
    for _ in range(iterations):
        c = np.array(split_coefficients([NOMINAL.name, *chosen], fitted.solve(cols))["inertia"])
        ratio = np.clip((J - c) / J, 1 / INERTIA_SHARE[1], 1 / INERTIA_SHARE[0])  # J / (J + dJ), dJ = c J / (J - c)
        new = np.ones((6, g.P))
        new[3:, :] = ratio[:, None]
        new[3:, own] = 1.0
        if np.allclose(new, scale, rtol=1e-6):
            break
        scale = new
        fitted = base.scaled(scale)
    return fitted


def channels_of(search: Search, name: str, theta: np.ndarray, delay: float) -> tuple[str, ...]:
    """Channels where an entry's fitted wrench carries at least a fifth of its largest (in noise units)."""
    X = np.concatenate([fd.features[name] for fd in search.data(delay)])
    w = (X @ theta) * search.weights
    rms = np.sqrt((w ** 2).mean(axis=0))
    if rms.max() <= 0:
        return ()
    return tuple(CHANNELS[c] for c in np.flatnonzero(rms >= 0.2 * rms.max()))
