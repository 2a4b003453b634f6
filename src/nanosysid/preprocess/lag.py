"""The motor telemetry's lag behind the accelerometer: a property of the rig, estimated once per
session.

The paper's method is the lag that maximises the cross-correlation of ``a_z`` with the sum of
squared rotor speeds (:func:`xcorr_lag`, whole flights). In closed loop that correlation peaks
early: the controller answers every disturbance of ``a_z`` through the rotors. With the host's
setpoints as instruments (the reference's thrust, which the disturbances do not move), the lag
is read from the flights' transients and carries an interval from blocks of flights
(:func:`motor_lag_estimate`); where the setpoints are missing, the whole-flight correlation.

Lags are searched on a 2 ms grid with parabolic refinement of the correlation peak.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np
import pandas as pd
from numpy.lib.stride_tricks import sliding_window_view
from scipy import stats
from scipy.constants import g as STANDARD_GRAVITY
from scipy.signal import butter, sosfiltfilt
from scipy.spatial.transform import Rotation

from nanosysid.errors import DataError

if TYPE_CHECKING:  # the settings' type only: sync imports this module
    from nanosysid.preprocess.sync import SyncConfig

__all__ = ["xcorr_lag", "LagEvidence", "LagEstimate", "motor_lag_evidence", "motor_lag_estimate", "INSTRUMENTED",
           "WHOLE_FLIGHT"]

def xcorr_lag(a: np.ndarray, b: np.ndarray, dt: float, max_lag: float,
              band: tuple[float, float] | None = None) -> float:
    """Lag (s) by which ``b`` follows ``a``: ``b(t) ≈ a(t - lag)``; both on one grid of step dt.

    With ``band`` (Hz), both signals are band-passed (zero phase) before correlating.
    """
    if band is not None:
        sos = butter(2, band, "bandpass", fs=1.0 / dt, output="sos")
        a, b = sosfiltfilt(sos, a), sosfiltfilt(sos, b)
    a = a - a.mean()
    b = b - b.mean()
    n = len(a)
    m = int(round(max_lag / dt))
    size = 1 << int(np.ceil(np.log2(2 * n)))
    cc = np.fft.irfft(np.fft.rfft(b, size) * np.conj(np.fft.rfft(a, size)), size)
    lags = np.arange(-m, m + 1)
    return _peak(cc[lags % size]) * dt


def _xcov(a: np.ndarray, b: np.ndarray, m: int) -> np.ndarray:
    """``sum_t a(t) b(t + k)`` for k = -m..m, ``(2m + 1,)``."""
    size = 1 << int(np.ceil(np.log2(len(a) + len(b) + m)))
    cc = np.fft.irfft(np.fft.rfft(b, size) * np.conj(np.fft.rfft(a, size)), size)
    return cc[np.arange(-m, m + 1) % size]


def _peak(vals: np.ndarray) -> float:
    """Offset (in grid steps, from the centre of ``vals``, lags -m..m) of the maximum, refined
    by a parabola through it and its neighbours."""
    m = (len(vals) - 1) // 2
    k = int(np.argmax(vals))
    lag = float(k - m)
    if 0 < k < len(vals) - 1:
        y0, y1, y2 = vals[k - 1], vals[k], vals[k + 1]
        den = y0 - 2 * y1 + y2
        if den != 0:
            lag += 0.5 * (y0 - y2) / den
    return lag


@dataclass(frozen=True)
class LagEvidence:
    """What one flight says about the motor telemetry's lag behind the accelerometer.

    Attributes:
        flight: The flight's name.
        step: Grid step (s) of the signals and of the lags.
        az, proxy: ``a_z`` and the thrust proxy ``sum Omega^2`` on one grid of the STM32
            clock (telemetry stamps as recorded), both band-passed.
        background: Robust standard deviation of the proxy's rate of change (1/s per step):
            the scale of the loop's answers to the disturbances.
        instrument: The thrust the host's position setpoints ask for, ``|p_ref'' + g e_z|``
            (m/s^2), band-passed on the same grid and zero where the instrument's moments would
            reach past the record; None without setpoints.
        velocity: The body-z velocity (m/s) from the onboard estimate, band-passed on the same
            grid: the drag along the thrust axis, which follows the reference as the thrust does.
    """

    flight: str
    step: float
    az: np.ndarray
    proxy: np.ndarray
    background: float
    instrument: np.ndarray | None = None
    velocity: np.ndarray | None = None


@dataclass(frozen=True)
class LagEstimate:
    """A motor lag (s) with its 95 % interval from independent repeats.

    ``events`` counts the transients it rests on (0 with instruments, and for the whole-flight
    fallback), ``units`` the repeats its interval comes from (blocks with instruments; flights for
    a session, transients for one flight without),
    ``background`` is the rate-of-change scale its transients stood out from and ``threshold``
    the rate of change (same units) a transient exceeded.
    """

    value: float
    interval: tuple[float | None, float | None]
    method: str
    events: int
    units: int
    background: float
    threshold: float


def motor_lag_evidence(name: str, imu: pd.DataFrame, motors: pd.DataFrame, cfg: SyncConfig, *,
                       setpoint: pd.DataFrame | None = None, odom: pd.DataFrame | None = None) -> LagEvidence:
    """``a_z`` and ``sum Omega^2`` of one flight on a common grid, band-passed to ``cfg.xcorr_band``;
    with ``setpoint`` (``t_src`` on the STM32 clock, ``x, y, z`` in m, zero outside the flight) and
    ``odom`` (``t_src``, the attitude ``qx..qw`` and the world-frame velocity ``vx, vy, vz``), the
    instrument and the body-z velocity too.

    Raises:
        DataError: the streams do not overlap, or no reading has all four rotors.
    """
    t_imu = imu["t_src"].to_numpy()
    t_mot = motors["t_src"].to_numpy()
    lo, hi = max(t_imu[0], t_mot[0]), min(t_imu[-1], t_mot[-1])
    if hi - lo < 2 * cfg.max_lag + 1.0:
        if hi - lo >= 1.0:  # they overlap: the search for the lag reaches beyond the flight
            raise DataError(f"{name}: the motor telemetry and the IMU overlap for {hi - lo:.3g} s, less than twice "
                            f"preprocess.sync.max_lag = {cfg.max_lag:g} s plus 1 s: a lag search that long needs a "
                            "longer flight, or a smaller max_lag")
        raise DataError(f"{name}: the motor telemetry and the IMU never overlap in time")
    step = cfg.xcorr_step
    tf = np.arange(lo, hi, step)
    m2 = motors[["m1", "m2", "m3", "m4"]].to_numpy()
    valid = ~np.isnan(m2).any(axis=1)
    if valid.sum() < 2:
        raise DataError(f"{name}: the motor telemetry has no complete reading of the four rotors")
    sos = butter(2, cfg.xcorr_band, "bandpass", fs=1.0 / step, output="sos")
    proxy = sosfiltfilt(sos, np.interp(tf, t_mot[valid], (m2[valid] ** 2).sum(axis=1)))
    az = sosfiltfilt(sos, np.interp(tf, t_imu, imu["az"].to_numpy()))
    rate = np.gradient(proxy)
    instrument = velocity = None
    if setpoint is not None and odom is not None:
        instrument = _reference_thrust(tf, setpoint, sos)
        if instrument is not None:
            reach = int(round(cfg.lag_reach / step)) + int(round(cfg.max_lag / step))
            instrument[:reach] = 0.0
            instrument[len(tf) - reach:] = 0.0
            q = odom[["qx", "qy", "qz", "qw"]].to_numpy(dtype=float, copy=True)
            v_body = Rotation.from_quat(q).inv().apply(odom[["vx", "vy", "vz"]].to_numpy(dtype=float, copy=True))[:, 2]
            velocity = sosfiltfilt(sos, np.interp(tf, odom["t_src"].to_numpy(), v_body))
    return LagEvidence(name, step, az - az.mean(), proxy - proxy.mean(),
                       float(1.4826 * np.median(np.abs(rate - np.median(rate)))), instrument, velocity)


def _reference_thrust(tf: np.ndarray, setpoint: pd.DataFrame, sos: np.ndarray) -> np.ndarray | None:
    """``|p_ref'' + g e_z|`` of the setpoints (second differences over their own stamps, inside the
    flight only, held outside it) on the grid ``tf``, band-passed; None where the flight has fewer
    than three setpoints."""
    p = setpoint[["x", "y", "z"]].to_numpy()
    on = np.linalg.norm(p, axis=1) > 0
    t = setpoint["t_src"].to_numpy()[on]
    if len(t) < 3 or not np.all(np.diff(t) > 0):
        return None
    acc = np.gradient(np.gradient(p[on], t, axis=0), t, axis=0)
    thrust = np.linalg.norm(acc + np.array([0.0, 0.0, STANDARD_GRAVITY]), axis=1)
    return sosfiltfilt(sos, np.interp(tf, t, thrust))


def _transient_curves(e: LagEvidence, threshold: float, window: float, m: int) -> np.ndarray:
    """``(E, 2m + 1)``: the cross-covariance of ``a_z`` with the proxy over the window around
    each transient (the proxy changing faster than ``threshold``)."""
    sharp = np.abs(np.gradient(e.proxy)) > threshold
    w = int(round(window / e.step))
    edges = np.flatnonzero(np.diff(np.r_[0, sharp.astype(np.int8), 0]))
    spans: list[list[int]] = []
    for a, b in zip(edges[::2], edges[1::2]):
        a, b = a - w, b + w
        if spans and a <= spans[-1][1]:
            spans[-1][1] = b
        else:
            spans.append([a, b])
    # windows clipped so that every lag of the search stays inside the flight
    spans = [[max(a, m), min(b, len(e.proxy) - m)] for a, b in spans]
    curves = [_xcov(e.az[a:b], e.proxy[a - m:b + m], 2 * m)[2 * m:4 * m + 1] for a, b in spans if b - a > w]
    return np.array(curves).reshape(-1, 2 * m + 1)


# The methods of the instrumented estimate and of the fallback, as LagEstimate.method says them.
INSTRUMENTED = "the setpoints as instruments"
WHOLE_FLIGHT = "whole-flight correlation"


def _block_moments(e: LagEvidence, reach: int, search: int, block: int) -> list[tuple[np.ndarray, ...]]:
    """The instrument's moments over each block of ``block`` grid steps of one flight:
    ``sum_t z(t) x(t + k)`` for ``a_z`` and the body-z velocity (k = -reach..reach) and for the
    proxy (k = -reach - search..reach + search); blocks where the instrument is zero are left out."""
    z = e.instrument
    lo, hi = reach + search, len(z) - reach - search
    out = []
    for a in range(lo, hi, block):
        b = min(a + block, hi)
        zb = z[a:b]
        if not zb.any():
            continue
        out.append((np.correlate(e.az[a - reach:b + reach], zb, "valid"),
                    np.correlate(e.proxy[a - reach - search:b + reach + search], zb, "valid"),
                    np.correlate(e.velocity[a - reach:b + reach], zb, "valid")))
    return out


def _normal_terms(ra: np.ndarray, rp: np.ndarray, rv: np.ndarray) -> np.ndarray:
    """``(2 search + 1, 5)``: for every lag, the normal equations' terms of one flight's moment
    conditions ``r_a(k) = c r_p(k + lag) + b r_v(k)``: ``p.p, p.v, v.v, p.a, v.a``."""
    P = sliding_window_view(rp, len(ra))
    return np.column_stack([(P * P).sum(1), P @ rv, np.full(len(P), rv @ rv), P @ ra, np.full(len(P), rv @ ra)])


def _explained(terms: np.ndarray) -> np.ndarray:
    """The share of the ``a_z`` moments the fit explains at every lag (0 where the thrust's
    coefficient comes out negative)."""
    pp, pv, vv, pa, va = terms.T
    det = pp * vv - pv * pv
    ok = det > 1e-12 * np.maximum(pp * vv, 1e-300)
    det = np.where(ok, det, 1.0)
    c = (pa * vv - va * pv) / det
    fit = (pa * pa * vv - 2 * pa * va * pv + va * va * pp) / det
    return np.where(ok & (c > 0), fit, 0.0)


def _instrumented_lag(evidence: Sequence[LagEvidence], cfg: SyncConfig) -> tuple[float, tuple[float, float], int] | None:
    """The lag (s) from the instrument's moment conditions of every flight, with its 95 % interval
    (a delete-one-block jackknife with Student's t) and the number of blocks; None where fewer than
    two blocks carry the instrument."""
    step = evidence[0].step
    reach, search = int(round(cfg.lag_reach / step)), int(round(cfg.max_lag / step))
    block = max(int(round(cfg.lag_block / step)), 1)
    flights = [_block_moments(e, reach, search, block) for e in evidence if e.instrument is not None]
    flights = [f for f in flights if f]
    n = sum(len(f) for f in flights)
    if n < 2:
        return None
    sums = [tuple(np.sum(x, axis=0) for x in zip(*f)) for f in flights]
    terms = [_normal_terms(*m) for m in sums]
    total = np.sum(terms, axis=0)
    curve = _explained(total)
    if not curve.any():
        return None
    value = _peak(curve) * step
    loo = []
    for f, blocks in enumerate(flights):
        for ra, rp, rv in blocks:
            ma, mp, mv = sums[f]
            loo.append(_peak(_explained(total - terms[f] + _normal_terms(ma - ra, mp - rp, mv - rv))) * step)
    loo = np.array(loo)
    half = float(stats.t.ppf(0.975, n - 1)) * float(np.sqrt((n - 1) / n * ((loo - loo.mean()) ** 2).sum()))
    return value, (value - half, value + half), n


# The steps (times ``lag_threshold``) down which a rig's threshold is relaxed until its transients
# give an interval. A rig with strong thrust disturbances answers them with fast rotor-speed
# changes, which raise the background its reference steps must stand out from: with the
# threshold fixed, such a session has no transient and falls back on the biased whole-flight
# correlation (tens of milliseconds early, with no interval).
RELAX = (1.0, 0.8, 0.6, 0.5, 0.4)


def motor_lag_estimate(evidence: Sequence[LagEvidence], cfg: SyncConfig, *,
                       threshold: float | None = None) -> LagEstimate:
    """The motor lag of one rig (a recording session, or one flight): with the host's setpoints
    as instruments where the evidence has them, else read off its sharp thrust transients.

    With instruments (the default, ``threshold`` None): the thrust the setpoints ask for,
    ``z(t) = |p_ref'' + g e_z|``, is set by the reference, not by the disturbances, so its moments
    ``r_x(k) = sum_t z(t) x(t + k)`` obey ``r_a(k) = c r_p(k + lag) + b r_v(k)`` for
    ``a_z``, the proxy ``sum Omega^2`` as recorded and the body-z velocity (the drag along the
    thrust axis, which follows the reference too), whatever the loop answers to the
    disturbances. The lag is the one whose fit of these conditions (k within
    ``cfg.lag_reach`` s, stacked over the flights) explains most of the ``a_z`` moments; its
    95 % interval a delete-one-block jackknife (blocks of ``cfg.lag_block`` s, Student's t).
    ``events`` is 0 and ``units`` the blocks.

    Without instruments: the closed loop answers every thrust disturbance through the rotor speeds a few tens of
    milliseconds later, so over a whole smooth flight the correlation of ``a_z`` with
    ``sum Omega^2`` peaks early (towards zero lag). A sharp transient is set by the reference,
    not by a disturbance: the proxy changes there ``cfg.lag_threshold`` times faster than the
    background of the loop's answers (the median flight's robust scale, so a flight made only of
    smooth motion has no transient), and there the peak sits at the telemetry's lag. Where the
    transients do not give two independent repeats, the threshold is relaxed down the steps of
    :data:`RELAX` until they do (else the highest threshold any transient passed is kept);
    ``threshold`` (a rate of change, as :attr:`LagEstimate.threshold`) fixes it instead, as for a
    flight's own estimate beside its session's. The lag is the peak of the cross-covariances
    summed over every transient of every flight; its 95 % interval a delete-one jackknife with
    Student's t over the independent repeats: the flights when several have transients, else
    the transients of the one. With no transient anywhere, the peak of the whole-flight
    correlations (biased in closed loop).
    """
    step = evidence[0].step
    m = int(round(cfg.max_lag / step))
    scale = float(np.median([e.background for e in evidence]))
    if threshold is None:
        found = _instrumented_lag(evidence, cfg)
        if found is not None:
            value, interval, n = found
            return LagEstimate(value, interval, INSTRUMENTED, 0, n, scale, cfg.lag_threshold * scale)
    steps = [threshold] if threshold is not None else [f * cfg.lag_threshold * scale for f in RELAX]
    found = None
    for limit in steps:
        curves = [_transient_curves(e, limit, cfg.lag_window, m) for e in evidence]
        counts = [len(c) for c in curves]
        if not sum(counts):
            continue
        units = ([c.sum(0) for c in curves if len(c)] if sum(n > 0 for n in counts) > 1
                 else list(np.concatenate(curves)))
        found = found or (limit, counts, units)
        if len(units) > 1:
            found = (limit, counts, units)
            break
    if found is None:
        whole = [_xcov(e.az, e.proxy, m) for e in evidence]
        value = _peak(np.sum([c / max(np.abs(c).max(), 1e-300) for c in whole], axis=0)) * step
        return LagEstimate(value, (None, None), WHOLE_FLIGHT, 0, 0, scale, steps[-1])
    limit, counts, units = found
    total = np.sum(units, axis=0)
    value = _peak(total) * step
    n = len(units)
    interval: tuple[float | None, float | None] = (None, None)
    if n > 1:
        loo = np.array([_peak(total - u) * step for u in units])
        se = float(np.sqrt((n - 1) / n * ((loo - loo.mean()) ** 2).sum()))
        half = float(stats.t.ppf(0.975, n - 1)) * se
        interval = (value - half, value + half)
    method = "sharp thrust transients"
    if threshold is None and limit != steps[0]:
        method += f" (threshold relaxed to {limit / scale:.3g} times the background)"
    return LagEstimate(value, interval, method, int(sum(counts)), n, scale, limit)
