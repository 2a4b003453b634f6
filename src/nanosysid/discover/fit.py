"""Measured against predicted body wrench, and the regression data every test of discovery reads.

The measured wrench is what the rigid body must have felt: force ``m a_IMU`` from the
accelerometer, torque ``J dω/dt + ω × Jω`` from the gyro (Savitzky-Golay derivative, as the
identify stage). The nominal model predicts ``[0, 0, k_F ΣΩ²]`` and the paper's mixer torques.
Their difference, per channel, is what the candidates must explain. Model-side signals are
smoothed with the same Savitzky-Golay window, so the filter does not show up as a disagreement.

Every fit is a least-squares problem over the six channels, each weighted by the inverse of
its noise floor (both parts of :func:`noise_parts` together: estimated from the measurements,
not from any simulator setting), so a weighted sum of squares counts noise variances. The samples are cut into
blocks of a few seconds, longer than the correlation of the smoothed noise and of slow
disturbances; blocks are dealt round-robin to ``folds`` folds, and every score is held out: fitted on
the other folds, measured on the block. :class:`Grams` keeps each block's normal equations, so
that a fit of any set of columns on any set of blocks is one small solve.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from nanosysid import effects
from nanosysid.dynamics import ROTOR_X, ROTOR_Y, SPIN, rotor_wrench
from nanosysid.dataio import Flight
from nanosysid.identify import body_torque
from nanosysid.rollout import advance_inputs
from nanosysid.vehicle import Vehicle

__all__ = ["FlightData", "flight_data", "nominal_wrench", "measured_wrench", "noise_parts",
           "noise_spectrum", "Grams", "EDGE", "ChainFilter", "local_noise", "local_floor", "input_noise", "input_noise_draws",
           "input_noise_grams",
           "COLUMN_ENTRIES", "VELOCITIES", "with_position_velocity"]

EDGE = 10  # samples dropped at each end of a flight: the smoothing filter's edge effects

# the entries whose columns the regression holds: the nominal refit, then every library entry
# with columns (input_delay is a search over the data, not a column)
COLUMN_ENTRIES = (effects.NOMINAL.name,) + tuple(n for n, e in effects.LIBRARY.items() if e.columns is not None)
_COLUMN_ENDS = np.cumsum([effects.entry(n).n_columns for n in COLUMN_ENTRIES])


# where the regressors' velocity comes from: the recorded velocity (an onboard estimate), or the
# derivative of the recorded position (motion capture's, where the flights hold it)
VELOCITIES = ("estimate", "position")


def with_position_velocity(flight: Flight, window: int, order: int) -> Flight:
    """``flight`` with its velocity ``y[:, 3:6]`` replaced by the Savitzky-Golay derivative of its
    position (m/s, the same ``window`` and ``order`` as every other derivative here).

    An onboard velocity estimate carries a slow error (its correlation time is seconds, so
    neither the smoothing nor the blocks average it out); through every drag column it leaves a
    torque and force residual that is a function of time, not of the state. A motion-capture
    position differentiated has white noise only.
    """
    from scipy.signal import savgol_filter

    dt = float(np.median(np.diff(flight.t)))
    y = flight.y.copy()
    y[:, 3:6] = savgol_filter(flight.y[:, 0:3], window, order, deriv=1, delta=dt, axis=0)
    return dataclasses.replace(flight, y=y)


def measured_wrench(flight: Flight, vehicle: Vehicle, window: int, order: int) -> np.ndarray:
    """``[m a_IMU; J dω/dt + ω × Jω]`` in the body frame, ``(T, 6)``."""
    acc = np.column_stack([flight.extra[c] for c in ("ax_body", "ay_body", "az_body")])
    force = vehicle.mass * _smooth(acc, window, order)
    return np.column_stack([force, body_torque(flight, vehicle.inertia, window=window, polyorder=order)])


def nominal_wrench(u: np.ndarray, vehicle: Vehicle) -> np.ndarray:
    """The quadratic rotor model's ``[0, 0, T; tau]``, ``(T, 6)``."""
    thrust, tau = rotor_wrench(torch.from_numpy(u), k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm)
    w = np.zeros((len(u), 6))
    w[:, 2] = thrust.numpy()
    w[:, 3:] = tau.numpy()
    return w


@dataclass(frozen=True)
class ChainFilter:
    """The zero-phase Butterworth low-passes the data chain ran each signal through (cut-off
    Hz; None: not filtered), all of one ``order``: the shape of each signal's noise."""

    accel: float | None = None
    gyro: float | None = None
    rotor: float | None = None
    order: int = 4

    def response(self, signal: str, dt: float, n: int = 201) -> np.ndarray:
        """Impulse response of ``signal``'s filter, ``(n,)`` centred (a unit impulse: none)."""
        b = np.zeros(n)
        b[n // 2] = 1.0
        cutoff = getattr(self, signal)
        if not cutoff:
            return b
        from scipy.signal import butter, sosfiltfilt

        return sosfiltfilt(butter(int(self.order), float(cutoff), "lowpass", fs=1.0 / dt, output="sos"), b)

    def apply(self, signal: str, a: np.ndarray, dt: float) -> np.ndarray:
        """``a`` through ``signal``'s filter along axis 0."""
        cutoff = getattr(self, signal)
        if not cutoff:
            return a
        from scipy.signal import butter, sosfiltfilt

        return sosfiltfilt(butter(int(self.order), float(cutoff), "lowpass", fs=1.0 / dt, output="sos"), a, axis=0)


# s: the span over which a signal's noise level is taken as constant (the rotors' vibration
# moves it within a flight)
NOISE_SPAN = 0.3


def local_noise(a: np.ndarray, dt: float, response: np.ndarray) -> np.ndarray:
    """Std of the white noise on each column of ``a (T, k)`` at each sample, before the filter
    of impulse response ``response`` (a unit impulse: unfiltered): the root mean square second
    difference over :data:`NOISE_SPAN` s (the flight's slow motion barely moves a second
    difference), turned into the std of the white noise through the norm of the second
    difference and the filter together."""
    from scipy.ndimage import uniform_filter1d

    through_d2 = float(np.sqrt((np.convolve(response, [1.0, -2.0, 1.0]) ** 2).sum()))
    span = max(3, int(round(NOISE_SPAN / dt)) | 1)
    level = np.sqrt(uniform_filter1d(np.diff(a, n=2, axis=0) ** 2, span, axis=0, mode="nearest")) / through_d2
    return np.concatenate([level[:1], level, level[-1:]])  # a second difference's sample is its middle one


def _through(response: np.ndarray, kernel: np.ndarray) -> float:
    """The std of white noise of unit std through ``response``, then ``kernel``."""
    return float(np.sqrt((np.convolve(response, kernel) ** 2).sum()))


def local_floor(flight: Flight, vehicle: Vehicle, window: int, order: int,
                chain: ChainFilter | None = None) -> np.ndarray:
    """Variance of the measurement noise in each channel of the smoothed residual at each sample,
    ``(T, 2, 6)`` in N² and N² m²: the part through the Savitzky-Golay smoothing (the
    accelerometer's, the nominal wrench's from the recorded rotor speeds) and the part through
    its derivative (the gyro's), each from the sample's local level (:func:`local_noise`: the
    noise grows where the rotors vibrate) through the data chain's filters (``chain``)."""
    from scipy.signal import savgol_coeffs

    chain = chain or ChainFilter()
    dt = float(np.median(np.diff(flight.t)))
    smooth, deriv = savgol_coeffs(window, order), savgol_coeffs(window, order, deriv=1, delta=dt)
    out = np.zeros((len(flight.t), 2, 6))
    a = np.column_stack([flight.extra[c] for c in ("ax_body", "ay_body", "az_body")])
    b = chain.response("accel", dt)
    out[:, 0, :3] = (vehicle.mass * local_noise(a, dt, b) * _through(b, smooth)) ** 2
    b = chain.response("rotor", dt)
    out[:, 0] += (local_noise(nominal_wrench(flight.u, vehicle), dt, b) * _through(b, smooth)) ** 2
    b = chain.response("gyro", dt)
    out[:, 1, 3:] = (np.asarray(vehicle.inertia) * local_noise(flight.y[:, 10:13], dt, b) * _through(b, deriv)) ** 2
    return out


def noise_parts(flights: Sequence[Flight], vehicle: Vehicle, window: int, order: int,
                chain: ChainFilter | None = None) -> np.ndarray:
    """Std of the measurement noise in each channel of the smoothed residual, ``(2, 6)`` in N and
    N m, its two parts (:func:`local_floor`) averaged in variance over every sample of every
    flight: estimated from the data themselves."""
    return np.sqrt(np.concatenate([local_floor(f, vehicle, window, order, chain) for f in flights]).mean(axis=0))


def noise_spectrum(parts: np.ndarray, window: int, order: int, dt: float, n: int) -> np.ndarray:
    """The power spectrum ``(n // 2 + 1,)`` of unit-variance noise made of ``parts`` (the
    variance shares through the Savitzky-Golay smoothing and through its derivative, summing to
    1) on ``np.fft.rfftfreq(n, dt)``: white noise carried through each filter, whose power is
    ``|H(f)|² / Σh²`` per unit of variance (a white noise's is 1 in every bin; a windowed
    segment's expected ``|rfft|²`` is this times the sum of the squared window)."""
    from scipy.signal import savgol_coeffs

    out = np.zeros(n // 2 + 1)
    for share, deriv in zip(parts, (0, 1)):
        h = savgol_coeffs(window, order, deriv=deriv, delta=dt)
        gain = np.abs(np.fft.rfft(h, n=n)) ** 2 / (h ** 2).sum()
        out += share * gain
    return out


@dataclass
class FlightData:
    """One flight's regression data for one rotor-speed delay, smoothed and trimmed at the edges.

    Attributes:
        r: The residual wrench ``(T, 6)``.
        features: Each entry of :data:`COLUMN_ENTRIES`' columns ``(T, 6, P)``.
        terms: The generic terms' signals :data:`nanosysid.effects.TERM_SIGNALS` ``(T, S)``.
        t: Time of each sample (s).
    """

    name: str
    r: np.ndarray
    features: dict[str, np.ndarray] = field(default_factory=dict)
    terms: np.ndarray | None = None
    t: np.ndarray | None = None


def flight_data(flight: Flight, vehicle: Vehicle, delay: float, *, window: int = 15, order: int = 3,
                measured: np.ndarray | None = None, force_bias: bool = False,
                lag_in_k_f: Sequence[float] = ()) -> FlightData:
    """The residual and the candidates' features of a flight, rotor speeds advanced by ``delay``;
    ``force_bias``: the force channels' flight means taken out of the residual and the columns
    (an accelerometer's bias is new at each power-up: a constant force of the flight's own that
    no effect makes, told apart from the effects by how they vary within the flight);
    ``lag_in_k_f``: what ``vehicle``'s k_F took of a slow actuation (:func:`effects.lag_in_k_f`)."""
    dt = float(np.median(np.diff(flight.t)))
    u = advance_inputs(torch.from_numpy(flight.u)[None], delay / dt)[0].numpy()  # read delay later
    om_dot = _smooth(u, window, order, deriv=1, delta=dt)
    meas = measured_wrench(flight, vehicle, window, order) if measured is None else measured
    r = meas - _smooth(nominal_wrench(u, vehicle), window, order)
    x, om, od = (torch.from_numpy(np.ascontiguousarray(v)) for v in (flight.y, u, om_dot))
    slow = effects.slow_squares(om[None], dt)[0]
    vbat = flight.extra.get("vbat")
    vbat = None if vbat is None or not np.all(np.isfinite(vbat)) else torch.from_numpy(np.asarray(vbat, dtype=float))
    # every entry's columns in one array, smoothed in one call (the filter works column by
    # column, so each entry's are the same as smoothed alone), then cut into the entries' views
    every = _smooth(effects.features(COLUMN_ENTRIES, x, om, od, vehicle, s_slow=slow, vbat=vbat,
                                     lag_in_k_f=lag_in_k_f).numpy(), window, order)[EDGE:-EDGE]
    if force_bias:
        every[:, :3] -= every[:, :3].mean(axis=0)
    feats = dict(zip(COLUMN_ENTRIES, np.split(every, _COLUMN_ENDS[:-1], axis=-1)))
    sg = effects.signals(x, om, od)
    terms = np.column_stack([torch.as_tensor(fn(sg, vehicle)).numpy() * np.ones(len(flight))
                             for _, fn in effects.TERM_SIGNALS.values()])
    r = r[EDGE:-EDGE]
    if force_bias:
        r[:, :3] -= r[:, :3].mean(axis=0)
    return FlightData(flight.name, r, feats, _smooth(terms, window, order)[EDGE:-EDGE], flight.t[EDGE:-EDGE])


def rotor_products(flight: Flight, t: np.ndarray, delay: float, *, window: int = 15, order: int = 3) -> np.ndarray:
    """Functions of the rotor speeds one by one that no entry or generic term is made of, at the
    regression samples ``t`` (s) of ``flight``, smoothed as the residual is, ``(len(t), 21)``: the
    speeds' roll, pitch and yaw differences (rad/s) and their products with the body velocity and
    rates. Each rotor's drag from its own air velocity (``v + w x r_i``) and its thrust's
    unequal share make torques of this form; the library's drags weigh the rotors by their sum."""
    dt = float(np.median(np.diff(flight.t)))
    u = advance_inputs(torch.from_numpy(flight.u)[None], delay / dt)[0].numpy()
    diffs = u @ np.array([ROTOR_Y, ROTOR_X, SPIN], dtype=float).T  # (T, 3)
    x = torch.from_numpy(np.ascontiguousarray(flight.y))
    sg = effects.signals(x, torch.from_numpy(u), torch.zeros_like(torch.from_numpy(u)))
    state = np.column_stack([torch.as_tensor(c).numpy() for c in (*sg.v, *sg.w)])  # (T, 6)
    cols = np.column_stack([diffs, (diffs[:, :, None] * state[:, None, :]).reshape(len(u), -1)])
    cols = _smooth(cols, window, order)
    idx = np.clip(np.searchsorted(flight.t, t - 1e-9), 0, len(flight.t) - 1)
    return cols[idx]


def input_noise(flight: Flight, chain: ChainFilter | None = None) -> np.ndarray:
    """Std of the white noise each rotor speed carried before the data chain's filter (rad/s),
    at each sample of ``flight``, ``(T,)``: :func:`local_noise`, the four rotors' variances
    averaged."""
    dt = float(np.median(np.diff(flight.t)))
    return np.sqrt((local_noise(flight.u, dt, (chain or ChainFilter()).response("rotor", dt)) ** 2).mean(axis=1))


def input_noise_draws(flight: Flight, vehicle: Vehicle, delay: float, *, window: int, order: int,
                      chain: ChainFilter | None, draws: int, seed: int,
                      lag_in_k_f: Sequence[float] = ()) -> tuple[np.ndarray, np.ndarray]:
    """What the rotor speeds' noise does to the columns and the residual: ``draws`` draws of
    noise like the flight's own (:func:`input_noise`, through ``chain``'s rotor filter), each carried
    through every step the recorded speeds take (the delay, the squares' slow history, the
    smoothing) to :data:`COLUMN_ENTRIES`' columns ``(draws, T, 6, P)`` and the residual
    ``(draws, T, 6)``, at the regression samples. Each is half the difference of the speeds plus
    and minus the draw: the noise's first-order effect, its mean square part cancelled."""
    chain = chain or ChainFilter()
    dt = float(np.median(np.diff(flight.t)))
    std = input_noise(flight, chain)
    rng = np.random.default_rng(seed)
    x = torch.from_numpy(np.ascontiguousarray(flight.y))
    vbat = flight.extra.get("vbat")
    vbat = None if vbat is None or not np.all(np.isfinite(vbat)) else torch.from_numpy(np.asarray(vbat, dtype=float))

    def columns(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        om = advance_inputs(torch.from_numpy(u)[None], delay / dt)[0]
        od = torch.from_numpy(_smooth(om.numpy(), window, order, deriv=1, delta=dt))
        slow = effects.slow_squares(om[None], dt)[0]
        f = effects.features(COLUMN_ENTRIES, x, om, od, vehicle, s_slow=slow, vbat=vbat, lag_in_k_f=lag_in_k_f).numpy()
        return _smooth(f, window, order)[EDGE:-EDGE], -_smooth(nominal_wrench(om.numpy(), vehicle), window, order)[EDGE:-EDGE]

    dx, dr = [], []
    for _ in range(draws):
        noise = chain.apply("rotor", rng.standard_normal(flight.u.shape) * std[:, None], dt)
        (xp, rp), (xm, rm) = columns(flight.u + noise), columns(flight.u - noise)
        dx.append((xp - xm) / 2)
        dr.append((rp - rm) / 2)
    return np.stack(dx), np.stack(dr)


def input_noise_grams(draws: Sequence[tuple[np.ndarray, np.ndarray]], weights: np.ndarray, blocks: np.ndarray,
                      folds: int) -> "Grams":
    """What the rotor speeds' noise adds to each block's normal equations, in expectation, from
    every flight's :func:`input_noise_draws` (flights in order): ``E[dX^T dX]`` to the Gram and
    ``E[dX^T dr]`` to the moments. The same noise enters the residual and the columns made of
    the rotor speeds (errors in variables), so least squares credits a column with it, most
    where the speeds are noisiest; taking this away leaves the normal equations of noise-free
    columns."""
    n = draws[0][0].shape[0]
    X = np.concatenate([dx.transpose(1, 0, 2, 3) for dx, _ in draws]).reshape(-1, 6, draws[0][0].shape[-1])
    y = np.concatenate([dr.transpose(1, 0, 2) for _, dr in draws]).reshape(-1, 6)
    return Grams(X / np.sqrt(n), y / np.sqrt(n), weights, np.repeat(blocks, n), folds)


def _smooth(a: np.ndarray, window: int, order: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    # imported here: scipy.signal costs 0.6 s, and every predictor imports this package
    from scipy.signal import savgol_filter

    return savgol_filter(a, window, order, deriv=deriv, delta=delta, axis=0)


def block_ids(data: Sequence[FlightData], block: int) -> np.ndarray:
    """Block of every sample, flights in order, ``block`` samples a block (a flight's last,
    shorter piece joins its previous block)."""
    ids, start = [], 0
    for d in data:
        n = len(d.r)
        k = max(1, n // block)
        ids.append(start + np.minimum(np.arange(n) // block, k - 1))
        start += k
    return np.concatenate(ids)


class Grams:
    """Per-block normal equations of the weighted residual on a set of columns.

    Args:
        X: Columns ``(N, 6, P)``; y: residual ``(N, 6)``; weights: per channel ``(6,)``;
        blocks: block of every sample ``(N,)`` (0..B-1); folds: number of folds the blocks are
        dealt to.
    """

    def __init__(self, X: np.ndarray, y: np.ndarray, weights: np.ndarray, blocks: np.ndarray, folds: int) -> None:
        B = int(blocks.max()) + 1
        Xw = X * weights[None, :, None]
        yw = y * weights[None, :]
        P = X.shape[-1]
        self.G = np.zeros((B, 6, P, P))  # per block and channel
        self.h = np.zeros((B, 6, P))
        self.e = np.zeros((B, 6))
        # channel-major copies, so that each block's products are BLAS's (a tenth of einsum's
        # time); a flight's blocks are consecutive samples
        xc, yc = np.ascontiguousarray(Xw.transpose(1, 0, 2)), np.ascontiguousarray(yw.T)[..., None]
        order = np.argsort(blocks, kind="stable")
        if np.any(order != np.arange(len(blocks))):
            xc, yc = xc[:, order], yc[:, order]
        edges = np.searchsorted(blocks[order], np.arange(B + 1))
        for b in range(B):
            xb, yb = xc[:, edges[b]:edges[b + 1]], yc[:, edges[b]:edges[b + 1]]
            xt = xb.transpose(0, 2, 1)
            self.G[b] = xt @ xb
            self.h[b] = (xt @ yb)[..., 0]
            self.e[b] = (yb ** 2).sum(axis=(1, 2))
        self.B, self.P = B, P
        self.fold = np.arange(B) % folds
        self.folds = folds
        self.fixed_values: dict[int, float] = {}
        self.Gt, self.ht, self.et = self.G.sum(1), self.h.sum(1), self.e.sum(1)  # channels summed

    def minus(self, noise: "Grams") -> "Grams":
        """These normal equations with ``noise``'s Gram and moments taken away (its sums of
        squares kept: every score stays in the units of the noise floor the weights set)."""
        return self._like(self.G - noise.G, self.h - noise.h, self.e)

    def per_block(self, scale: np.ndarray) -> "Grams":
        """These normal equations with each block's channels weighted again: channel ``c`` of
        block ``b`` times ``scale[b, c]`` in variance (``scale`` ``(B, 6)``)."""
        return self._like(self.G * scale[:, :, None, None], self.h * scale[:, :, None], self.e * scale)

    def _like(self, G: np.ndarray, h: np.ndarray, e: np.ndarray) -> "Grams":
        g = object.__new__(Grams)
        g.G, g.h, g.e = G, h, e
        g.B, g.P, g.fold, g.folds, g.fixed_values = self.B, self.P, self.fold, self.folds, dict(self.fixed_values)
        g.Gt, g.ht, g.et = G.sum(1), h.sum(1), e.sum(1)
        return g

    def subset(self, blocks: np.ndarray, folds: int) -> "Grams":
        """The normal equations of ``blocks`` alone (renumbered in order), dealt to ``folds`` folds."""
        g = self._like(self.G[blocks], self.h[blocks], self.e[blocks])
        g.B, g.folds = len(blocks), folds
        g.fold = np.arange(len(blocks)) % folds
        return g

    def scaled(self, scale: np.ndarray) -> "Grams":
        """The same normal equations with every column scaled per channel: column ``p`` times
        ``scale[c, p]`` on channel ``c`` (``scale`` ``(6, P)``)."""
        return self._like(self.G * scale[None, :, :, None] * scale[None, :, None, :], self.h * scale[None], self.e)

    def fixed(self, col: int, value: float) -> "Grams":
        """The normal equations with column ``col``'s coefficient held at ``value``: its share
        moved to the residual, and :meth:`solve` gives ``value`` for it."""
        G, h = self.G.copy(), self.h - value * self.G[..., col]
        e = self.e - 2 * value * self.h[..., col] + value ** 2 * self.G[..., col, col]
        G[..., col, :] = 0.0
        G[..., :, col] = 0.0
        h[..., col] = 0.0
        g = self._like(G, h, e)
        g.fixed_values[col] = float(value)
        return g

    def solve(self, cols: np.ndarray, blocks: np.ndarray | None = None) -> np.ndarray:
        """Coefficients of columns ``cols`` fitted on ``blocks`` (all when None)."""
        idx = slice(None) if blocks is None else blocks
        A = self.Gt[idx].sum(0)[np.ix_(cols, cols)]
        b = self.ht[idx].sum(0)[cols]
        x = _solve(A, b)
        for i, c in enumerate(cols):
            if int(c) in self.fixed_values:
                x[i] = self.fixed_values[int(c)]
        return x

    def sse(self, cols: np.ndarray, theta: np.ndarray, blocks=slice(None), *, per_channel: bool = False) -> np.ndarray:
        """Weighted SSE of each block in ``blocks`` (per channel: ``(n, 6)``) left by ``theta``."""
        if per_channel:
            G, h, e = self.G[blocks][..., cols[:, None], cols[None, :]], self.h[blocks][..., cols], self.e[blocks]
            return e - 2 * h @ theta + np.einsum("bcpq,p,q->bc", G, theta, theta)
        G, h, e = self.Gt[blocks][:, cols[:, None], cols[None, :]], self.ht[blocks][:, cols], self.et[blocks]
        return e - 2 * h @ theta + np.einsum("bpq,p,q->b", G, theta, theta)

    def heldout(self, cols: np.ndarray, *, per_channel: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Each block's held-out SSE (fitted on the other folds), ``(B,)`` or ``(B, 6)``, and
        each fold's coefficients ``(folds, len(cols))``."""
        out = np.zeros((self.B, 6) if per_channel else self.B)
        thetas = np.zeros((self.folds, len(cols)))
        for k in range(self.folds):
            test = np.flatnonzero(self.fold == k)
            th = self.solve(cols, np.flatnonzero(self.fold != k))
            thetas[k] = th
            out[test] = self.sse(cols, th, test, per_channel=per_channel)
        return out, thetas


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least squares from normal equations, columns scaled to unit diagonal; a column that is
    zero on these blocks gets a zero coefficient."""
    if len(b) == 0:
        return np.zeros(0)
    d = np.sqrt(np.clip(np.diag(A), 0, None))
    ok = d > 1e-12 * max(d.max(), 1e-300)
    x = np.zeros(len(b))
    if ok.any():
        As = A[np.ix_(ok, ok)] / np.outer(d[ok], d[ok])
        x[ok] = np.linalg.lstsq(As, b[ok] / d[ok], rcond=1e-12)[0] / d[ok]
    return x
