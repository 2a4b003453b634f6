"""sync: bring the streams of one flight onto one clock and one uniform 100 Hz grid.

The paper's method (section Data Preprocessing), in order:

1. Clocks against the host. For every stream, the receive time is the source stamp mapped to
   host time plus a latency that is never negative; the lower envelope of ``t_recv - t_src``
   over one-second bins, fitted by a line, gives each clock's offset and drift (jitter only
   ever adds delay, so the envelope is the clean relation).
2. Motion capture against the STM32 clock. Mapped through the host first, then refined by
   the lag that maximises the cross-correlation of the mocap and onboard positions, averaged
   over x, y and z (the paper's method); this removes the difference of the latencies.
3. Motor telemetry against the accelerometer: the motor stamps are moved by the rig's lag,
   estimated once per session (:mod:`nanosysid.preprocess.lag`).
4. The flight segment: where the host's position setpoint is non-zero, mapped to STM32 time.
5. Resampling to the 100 Hz grid of the STM32 clock: nearest neighbour for the onboard streams
   (retiming, which also fills lost packets with the closest measurement), interpolation for
   the motion capture. A mask marks the samples with no measurement of their own.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd
from numpy.lib.stride_tricks import sliding_window_view
from scipy.spatial.transform import Rotation, Slerp
from tqdm.auto import tqdm

from nanosysid.dataio import atomic_dir, atomic_file, check_finite, session_of, write_json
from nanosysid.errors import ConfigError, DataError
from nanosysid.preprocess import STREAM_COLUMNS
from nanosysid.preprocess.lag import WHOLE_FLIGHT, LagEstimate, motor_lag_estimate, motor_lag_evidence, xcorr_lag
from nanosysid.settings import configured

__all__ = ["SyncConfig", "sync_flight", "sync_folder", "clock_fit", "onboard_clock", "setpoint_on_stm"]

log = logging.getLogger(__name__)

# the streams every recording has, and those the sync carries where it has them
STREAMS = ("mocap", "odom", "imu", "motors", "setpoint")
OPTIONAL_STREAMS = ("controller",)


@configured("preprocess/default.yaml", "sync")
class SyncConfig:
    """The sync stage's settings; their defaults and meaning: ``preprocess.sync`` of
    ``conf/preprocess/default.yaml``. The cross-correlations' band: the slow motion of the
    trajectory carries components that are not pure delays (drag, which follows velocity, in
    a_z) and would bias the peak, and above the band the sensors' noise dominates."""

    rate: float
    max_lag: float
    xcorr_band: tuple[float, float]
    xcorr_step: float
    min_samples: int
    position: str
    warn_loss: float
    warn_gap: int
    max_loss: float
    lag_threshold: float
    lag_window: float
    lag_tolerance: float
    lag_reach: float
    lag_block: float

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> "SyncConfig":
        kw = dict(cfg)
        if "xcorr_band" in kw:
            kw["xcorr_band"] = tuple(float(f) for f in kw["xcorr_band"])
        return cls(**kw)


def clock_fit(t_src: np.ndarray, t_recv: np.ndarray) -> tuple[float, float]:
    """``t_recv ≈ t_src * (1 + drift) + offset`` on the lower envelope; returns (drift, offset)."""
    d = t_recv - t_src
    bins = np.floor((t_src - t_src[0]) / 1.0).astype(int)
    order = np.lexsort((d, bins))
    first = np.r_[True, np.diff(bins[order]) != 0]
    idx = order[first]  # the least delayed sample of every 1 s bin
    if len(idx) < 2:
        return 0.0, float(d.min())
    drift, offset = np.polyfit(t_src[idx] - t_src[0], d[idx], 1)
    return float(drift), float(offset - drift * t_src[0])


def onboard_clock(odom: pd.DataFrame, imu: pd.DataFrame) -> tuple[float, float]:
    """The STM32 clock's drift and offset against the host (:func:`clock_fit` over the onboard
    streams): host time = ``t_stm * (1 + drift) + offset``."""
    onboard = pd.concat([odom[["t_src", "t_recv"]], imu[["t_src", "t_recv"]]]).sort_values("t_src")
    return clock_fit(onboard["t_src"].to_numpy(), onboard["t_recv"].to_numpy())


def setpoint_on_stm(setpoint: pd.DataFrame, drift: float, offset: float) -> pd.DataFrame:
    """The host's setpoints with their stamps mapped to the STM32 clock."""
    return setpoint.assign(t_src=(setpoint["t_src"].to_numpy() - offset) / (1 + drift))


def _grid_nearest(t_src: np.ndarray, t: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Index of the nearest source sample for every grid time, and the mask of grid times
    with no source sample within half a period."""
    j = np.clip(np.searchsorted(t_src, t), 1, len(t_src) - 1)
    left_closer = (t - t_src[j - 1]) <= (t_src[j] - t)
    j = np.where(left_closer, j - 1, j)
    missing = np.abs(t_src[j] - t) > 0.5 * period + 1e-9
    return j, missing


def sync_flight(name: str, tables: Mapping[str, pd.DataFrame], cfg: SyncConfig,
                motor_lag: "LagEstimate | None" = None) -> tuple[pd.DataFrame, dict]:
    """Synchronise and resample the streams of one flight.

    ``motor_lag`` is the lag of the motor telemetry to apply, a property of the rig estimated
    over the flights of one session (:func:`motor_lag_estimate`); None applies the flight's
    own estimate. The flight's own estimate is reported either way.

    Returns:
        The flight on its 100 Hz grid (published columns plus ``miss_*`` masks), and a report
        with the estimated clock relations, lags and losses.

    Raises:
        DataError: streams that never overlap, no flight segment, or a segment shorter than
            ``cfg.min_samples``.
    """
    period = 1.0 / cfg.rate
    mocap, odom, imu, motors, setp = (tables[k] for k in STREAMS)
    report: dict[str, Any] = {"flight": name}

    # 1. clocks against the host
    stm_drift, stm_off = onboard_clock(odom, imu)
    mc_drift, mc_off = clock_fit(mocap["t_src"].to_numpy(), mocap["t_recv"].to_numpy())

    def stm_to_host(t):
        return t * (1 + stm_drift) + stm_off

    def host_to_stm(h):
        return (h - stm_off) / (1 + stm_drift)

    # 2. mocap to STM32 time: through the host, then by position cross-correlation
    t_mc_coarse = host_to_stm(mocap["t_src"].to_numpy() * (1 + mc_drift) + mc_off)
    t_od = odom["t_src"].to_numpy()
    lo, hi = max(t_mc_coarse[0], t_od[0]), min(t_mc_coarse[-1], t_od[-1])
    if hi - lo < 2 * cfg.max_lag + 1.0:
        raise DataError(f"{name}: the motion capture and the onboard streams never overlap in time "
                        f"(mocap {t_mc_coarse[0]:.2f}..{t_mc_coarse[-1]:.2f} s, onboard {t_od[0]:.2f}..{t_od[-1]:.2f} s "
                        "on the STM32 clock)")
    tf = np.arange(lo, hi, cfg.xcorr_step)
    lags = []
    for c in "xyz":
        a = np.interp(tf, t_od, odom[c].to_numpy())
        b = np.interp(tf, t_mc_coarse, mocap[c].to_numpy())
        # mocap mapped coarsely trails the onboard estimate by the latency difference
        lags.append(float(xcorr_lag(a, b, cfg.xcorr_step, cfg.max_lag, cfg.xcorr_band)))
    mocap_lag = float(np.mean(lags))
    t_mc = t_mc_coarse - mocap_lag
    report["mocap_lag_axes"] = lags

    # 3. motors against the accelerometer: the session's lag when given, else the flight's own
    own = motor_lag_estimate([motor_lag_evidence(name, imu, motors, cfg)], cfg,
                             threshold=None if motor_lag is None else motor_lag.threshold)
    applied = own if motor_lag is None else motor_lag
    t_imu = imu["t_src"].to_numpy()
    m2 = motors[["m1", "m2", "m3", "m4"]].to_numpy()
    t_mot = motors["t_src"].to_numpy() - applied.value

    # 4. flight segment from the setpoints
    sp = setp[["x", "y", "z"]].to_numpy()
    on = np.linalg.norm(sp, axis=1) > 0
    if not on.any():
        raise DataError(f"{name}: the setpoint stream is zero throughout: no flight segment")
    h_start, h_end = setp["t_src"].to_numpy()[on][[0, -1]]
    s_start, s_end = host_to_stm(h_start), host_to_stm(h_end)
    k0, k1 = int(np.ceil(s_start * cfg.rate - 1e-6)), int(np.floor(s_end * cfg.rate + 1e-6))
    t = np.arange(k0, k1 + 1) / cfg.rate
    if len(t) < cfg.min_samples:
        raise DataError(f"{name}: the flight segment has {max(len(t), 0)} samples, fewer than the "
                        f"{cfg.min_samples} of one window")
    t = t[(t >= t_mc[0]) & (t <= t_mc[-1]) & (t >= t_od[0]) & (t <= t_od[-1])]
    if len(t) < cfg.min_samples:
        raise DataError(f"{name}: the streams cover {len(t)} samples of the flight segment, fewer than "
                        f"the {cfg.min_samples} of one window")

    # 5. resampling
    out = pd.DataFrame({"t": t})
    masks = {}
    j, masks["odom"] = _grid_nearest(t_od, t, period)
    for c in ("vx", "vy", "vz"):
        out[c] = odom[c].to_numpy()[j]
    j, masks["imu"] = _grid_nearest(t_imu, t, period)
    for src, dst in (("wx", "wx"), ("wy", "wy"), ("wz", "wz"), ("ax", "ax_body"), ("ay", "ay_body"), ("az", "az_body")):
        out[dst] = imu[src].to_numpy()[j]
    for i in range(4):
        col = m2[:, i]
        ok = ~np.isnan(col)
        j, miss = _grid_nearest(t_mot[ok], t, period)
        out[f"m{i + 1}_rads"] = col[ok][j]
        masks[f"m{i + 1}"] = miss
    # motion capture: interpolation between frames; samples inside a dropout are marked
    frame = np.median(np.diff(t_mc))
    right = np.clip(np.searchsorted(t_mc, t), 1, len(t_mc) - 1)
    masks["mocap"] = (t_mc[right] - t_mc[right - 1]) > 2.5 * frame
    for c in ("x", "y", "z"):
        out[c] = np.interp(t, t_mc, mocap[c].to_numpy())
    q = mocap[["qx", "qy", "qz", "qw"]].to_numpy()
    if np.isnan(q).all():
        # a motion capture without attitude (the rig's logs): the onboard estimate's, as measured
        j, masks["attitude"] = _grid_nearest(t_od, t, period)
        out[["qx", "qy", "qz", "qw"]] = odom[["qx", "qy", "qz", "qw"]].to_numpy()[j]
        report["attitude"] = "onboard estimate (the motion capture has none)"
    else:
        out[["qx", "qy", "qz", "qw"]] = Slerp(t_mc, Rotation.from_quat(q))(t).as_quat()
    # the host's yaw setpoint (zero outside the flight), held between its messages
    t_sp = host_to_stm(setp["t_src"].to_numpy())
    out["yaw_ref"] = setp["yaw"].to_numpy()[np.clip(np.searchsorted(t_sp, t + 1e-9) - 1, 0, len(t_sp) - 1)]
    if cfg.position == "onboard":
        # the onboard estimate's position (the benchmark's published flights hold it): a motion
        # capture dropout then leaves no gap in the position
        j, masks["position"] = _grid_nearest(t_od, t, period)
        for c in ("x", "y", "z"):
            out[c] = odom[c].to_numpy()[j]
    elif cfg.position != "mocap":
        raise ConfigError(f"preprocess.sync.position must be mocap or onboard, got {cfg.position!r}")
    # the controller's stream, where the recording has one: its commands and the battery's
    # voltage, carried as extra signals (nearest message)
    if tables.get("controller") is not None:
        ctl = tables["controller"]
        j, masks["controller"] = _grid_nearest(ctl["t_src"].to_numpy(), t, period)
        for c in ctl.columns[2:]:
            out[c] = ctl[c].to_numpy()[j]
    for k, m in masks.items():
        out[f"miss_{k}"] = m

    _check_coverage(name, t - t[0], masks, cfg.max_loss)
    _check_shared_ticks(name, imu["t_src"].to_numpy(), odom["t_src"].to_numpy(), t[0])
    _check_receive_step(name, imu, odom, t[0])
    _check_rotors(name, t - t[0], out, masks)
    _check_velocity_frame(name, t - t[0], out)

    report.update({
        "samples": int(len(t)),
        "t_start_stm": float(t[0]),
        "stm_drift": stm_drift,
        # STM32 time minus mocap time of the same instant, at the start of the flight
        "mocap_to_stm_offset": float(t[0] - np.interp(t[0], t_mc, mocap["t_src"].to_numpy())),
        "motor_lag": applied.value,
        "motor_lag_source": "flight" if motor_lag is None else "session",
        "motor_lag_interval": list(applied.interval),
        "motor_lag_method": applied.method,
        "motor_lag_flight": own.value if own.events else None,
        "motor_lag_flight_interval": list(own.interval) if own.events else None,
        "motor_lag_flight_events": own.events,
        "mocap_lag": mocap_lag,
        "missing": {k: float(m.mean()) for k, m in masks.items()},
        "longest_gap": {k: _longest_run(m) for k, m in masks.items()},
    })
    warnings = [f"{k}: {v:.1%} of samples missing" for k, v in report["missing"].items() if v > cfg.warn_loss]
    warnings += [f"{k}: {v} samples missing in a row" for k, v in report["longest_gap"].items() if v > cfg.warn_gap]
    if own.events and abs(own.value - applied.value) > cfg.lag_tolerance:
        warnings.append(f"motors: this flight's own lag {own.value * 1e3:.1f} ms is "
                        f"{abs(own.value - applied.value) * 1e3:.1f} ms off the {applied.value * 1e3:.1f} ms applied")
    if applied.method == WHOLE_FLIGHT:
        warnings.append("motors: no sharp thrust transient; the lag is the whole-flight correlation's, which the "
                        "closed loop biases towards zero")
    report["warnings"] = warnings
    if warnings:  # one line a flight: the sync report lists them one by one
        log.warning("%s: %s", name, "; ".join(warnings))
    return out, report


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def _check_coverage(name: str, t: np.ndarray, masks: Mapping[str, np.ndarray], max_loss: float) -> None:
    """Refuse a stream that misses more than ``max_loss`` of the flight: held values would stand
    for most of it."""
    for stream, miss in masks.items():
        if miss.mean() > max_loss:
            a, b = max(_runs(miss), key=lambda r: r[1] - r[0])
            raise DataError(f"{name}: stream {stream} misses {miss.mean():.0%} of the flight's samples (its longest "
                            f"gap {t[a]:.2f}..{t[b - 1]:.2f} s), more than preprocess.sync.max_loss = {max_loss:g}; "
                            "the recording lost that stream (check the topic and the link)")


# the onboard streams are stamped on the ticks of one clock where, over some STEP_S seconds, at
# least SHARED_TICKS of the IMU's stamps equal an odometry stamp (to TICK_MATCH_S); a step of the
# IMU's clock against the odometry's is then STEP_S seconds in which at most LEFT_TICKS do
SHARED_TICKS, LEFT_TICKS, TICK_MATCH_S, STEP_S = 0.9, 0.1, 1e-4, 0.5


def _tick_offsets(t_imu: np.ndarray, t_odom: np.ndarray) -> np.ndarray:
    """``(len(t_imu),)`` the nearest odometry stamp minus each IMU stamp (s); both sorted."""
    i = np.clip(np.searchsorted(t_odom, t_imu), 1, len(t_odom) - 1)
    return np.where(np.abs(t_odom[i] - t_imu) < np.abs(t_odom[i - 1] - t_imu), t_odom[i], t_odom[i - 1]) - t_imu


def _check_shared_ticks(name: str, t_imu: np.ndarray, t_odom: np.ndarray, t0: float) -> None:
    """Refuse IMU stamps that leave the ticks they shared with the odometry's: the IMU's clock
    stepped (the gyro would be moved against every other signal from there, by less than a
    sample, without a word). Streams on clocks of their own (no shared ticks) are not judged."""
    if len(t_imu) < 2 or len(t_odom) < 2:
        return
    off = _tick_offsets(t_imu, t_odom)
    on = np.abs(off) < TICK_MATCH_S
    period = float(np.median(np.diff(t_imu)))
    if not period > 0:  # stamps repeated more often than not: no rate to judge a step by
        return
    # a lost odometry message leaves one IMU stamp without its tick; a stepped clock, every one
    window = min(len(on), max(1, int(round(STEP_S / period))))
    share = np.convolve(on.astype(float), np.ones(window) / window, mode="valid")
    if share.max() < SHARED_TICKS or share.min() > LEFT_TICKS:
        return
    a = int(np.argmin(share))
    step = float(np.median(off[a:a + window]))
    raise DataError(f"{name}: from {t_imu[a] - t0:.2f} s the IMU's stamps are {-step * 1e3:+.1f} ms off the "
                    "odometry's, whose clock ticks they share elsewhere in the flight: the IMU's clock stepped, "
                    "and its signals would be moved against the others from there; the recording's IMU "
                    "timestamps are damaged")


# A step of the IMU's clock by whole ticks keeps its stamps on the odometry's ticks; the host's
# receive times still show it. Per RECEIVE_BIN_S of flight, the least delay of each stream (host
# time minus stamp: the link's fastest message, the line clock_fit draws) is the clock offset plus
# the shortest transit, the same for two streams of one clock over one link; a step moves the
# IMU's alone. A bin is judged when both streams have RECEIVE_MIN messages in it, and a level
# holds over RECEIVE_RUN judged bins (a median of them): a lone late bin (the rig's logs have a
# few of up to 10 ms) is no step. Streams are on one clock where RECEIVE_SHARED of the IMU's stamps
# fall on an odometry tick (two clocks of their own meet within TICK_MATCH_S on a few per cent; the
# rig's logs, which lose rows of one stream and not the other, share 80 % and more)
RECEIVE_BIN_S, RECEIVE_MIN, RECEIVE_RUN, RECEIVE_SHARED = 1.0, 10, 3, 0.5


def _least_delays(t_src: np.ndarray, t_recv: np.ndarray, h0: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(n,)`` least ``t_recv - t_src`` of each bin of RECEIVE_BIN_S of host time from ``h0`` (NaN
    where empty) and ``(n,)`` the bin's message count. Binned by the host's time, which a stamp's
    step does not move: both streams' bins hold the same stretch of the link."""
    b = np.floor((t_recv - h0) / RECEIVE_BIN_S).astype(int)
    keep = (b >= 0) & (b < n)
    least = np.full(n, np.inf)
    np.minimum.at(least, b[keep], (t_recv - t_src)[keep])
    return np.where(np.isfinite(least), least, np.nan), np.bincount(b[keep], minlength=n)


def _check_receive_step(name: str, imu: pd.DataFrame, odom: pd.DataFrame, t0: float) -> None:
    """Refuse IMU stamps whose least receive delay steps against the odometry's by half a sample
    or more: the IMU's clock stepped by whole ticks (its gyro would sit a sample or more off
    every other signal from there, on ticks the odometry shares). Streams on clocks of their own
    (no shared ticks) are not judged."""
    t_imu, t_odom = imu["t_src"].to_numpy(), odom["t_src"].to_numpy()
    if len(t_imu) < 2 or len(t_odom) < 2:
        return
    period = float(np.median(np.diff(t_imu)))
    if not period > 0 or np.mean(np.abs(_tick_offsets(t_imu, t_odom)) < TICK_MATCH_S) < RECEIVE_SHARED:
        return
    h_odom = odom["t_recv"].to_numpy()
    # the host's time at the flight's start t0 (STM32), through the odometry's first message after it
    first = min(int(np.searchsorted(t_odom, t0)), len(t_odom) - 1)
    h0 = h_odom[first] - (t_odom[first] - t0)
    n = int((max(h_odom[-1], imu["t_recv"].to_numpy()[-1]) - h0) // RECEIVE_BIN_S) + 1
    d_imu, c_imu = _least_delays(t_imu, imu["t_recv"].to_numpy(), h0, n)
    d_odom, c_odom = _least_delays(t_odom, h_odom, h0, n)
    judged = np.flatnonzero((c_imu >= RECEIVE_MIN) & (c_odom >= RECEIVE_MIN))
    if len(judged) < 2 * RECEIVE_RUN:
        return
    gap = (d_imu - d_odom)[judged]
    level = np.median(sliding_window_view(gap, RECEIVE_RUN), axis=1)
    moved = np.flatnonzero(np.abs(level - level[0]) >= period / 2)
    if not len(moved):
        return
    k = int(moved[0])
    # the IMU's stamps later by s make its delay (host time minus stamp) s shorter
    step = float(level[0] - level[k])
    at = judged[k + RECEIVE_RUN // 2] * RECEIVE_BIN_S
    raise DataError(f"{name}: from about {at:.0f} s the IMU's stamps are {step * 1e3:+.1f} ms off the odometry's "
                    f"against the host's receive times ({step / period:+.1f} samples), on ticks the two share: "
                    "the IMU's clock stepped by whole ticks, and its signals would be moved against the others "
                    "from there; the recording's IMU timestamps are damaged")


# a rotor reading below this share of the flight's median rotor speed, on this many measured
# samples in a row, is stopped: a quadrotor cannot fly with a rotor stopped that long
STOPPED_SHARE, STOPPED_SAMPLES = 0.1, 3
# a rotor whose median speed over the flight is off the four rotors' median by more than this
# factor: a thrust 32 % off its neighbours' (speed squared) leaves a roll or pitch torque no
# attitude loop holds for a flight; the rig's and the world's rotors stay within 2.5 %
ROTOR_BALANCE = 1.15


def _check_rotors(name: str, t: np.ndarray, out: pd.DataFrame, masks: Mapping[str, np.ndarray]) -> None:
    """Refuse rotor readings of (nearly) zero while the vehicle flies."""
    speeds = out[[f"m{i}_rads" for i in range(1, 5)]].to_numpy()
    typical = np.median(speeds)
    for i in range(4):
        stopped = (speeds[:, i] < STOPPED_SHARE * typical) & ~masks[f"m{i + 1}"]
        for a, b in _runs(stopped):
            if b - a >= STOPPED_SAMPLES:
                raise DataError(f"{name}: motor m{i + 1} reads {speeds[a:b, i].max():.0f} rad/s from {t[a]:.2f} to "
                                f"{t[b - 1]:.2f} s while the others turn at about {typical:.0f} rad/s: a rotor cannot "
                                "stop in flight; the telemetry of that motor is wrong (or the flight segment "
                                "includes the ground)")
    medians = np.median(speeds, axis=0)
    ratio = medians / np.median(medians)
    off = np.flatnonzero((ratio > ROTOR_BALANCE) | (ratio < 1 / ROTOR_BALANCE))
    if off.size:
        raise DataError(f"{name}: " + "; ".join(
            f"motor m{i + 1} reads {ratio[i]:.2f} times the four rotors' median speed over the flight "
            f"({medians[i]:.0f} against {np.median(medians):.0f} rad/s)" for i in off)
            + f": a flying quadrotor's rotors turn within a factor {ROTOR_BALANCE:g} of each other; the "
            "telemetry of that motor is scaled wrong (another unit or gain) or is another motor's")


# the two frames are told apart where they differ by more than FRAME_APART (m/s RMS); the other
# frame is the recording's when it matches the motion capture FRAME_BETTER times as closely (in
# the right frame the other reading adds the frames' difference to the estimator's drift)
FRAME_APART, FRAME_BETTER = 0.05, 0.7


def _check_velocity_frame(name: str, t: np.ndarray, out: pd.DataFrame) -> None:
    """Refuse odometry velocities that match the motion capture's only after a rotation by the
    attitude: the topic map's ``odom.velocity_frame`` says the other frame."""
    if len(t) < 20:
        return
    dt = float(np.median(np.diff(t)))
    v_mc = np.gradient(out[["x", "y", "z"]].to_numpy(), dt, axis=0)
    v = out[["vx", "vy", "vz"]].to_numpy()
    attitude = Rotation.from_quat(out[["qx", "qy", "qz", "qw"]].to_numpy())
    # the position's derivative is noisy: compare the slow parts (half-second means)
    k = max(1, int(round(0.5 / dt)))
    n = len(t) // k * k

    def slow(x):
        return x[:n].reshape(-1, k, 3).mean(axis=1)

    given = float(np.sqrt(np.mean((slow(v) - slow(v_mc)) ** 2)))
    # recorded in the body frame but read as world, or the reverse (rotated where it should not be)
    for label, other in (("body-frame", attitude.apply(v)), ("world-frame", attitude.inv().apply(v))):
        err = float(np.sqrt(np.mean((slow(other) - slow(v_mc)) ** 2)))
        apart = float(np.sqrt(np.mean((slow(other) - slow(v)) ** 2)))
        if apart > FRAME_APART and err < FRAME_BETTER * given:
            raise DataError(f"{name}: the odometry velocities differ from the motion capture's by {given:.2f} m/s RMS, "
                            f"but by {err:.2f} m/s read as {label} values: preprocess.topics.odom.velocity_frame "
                            "does not match the recording (world: the velocity in the world frame; body: in the "
                            "vehicle's)")


def _longest_run(mask: np.ndarray) -> int:
    return max((b - a for a, b in _runs(mask)), default=0)


def extracted_flights(folder: Path) -> list[Path]:
    """The flight folders of the extract stage's output."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: no such folder")
    flights = sorted(p for p in folder.iterdir() if p.is_dir())
    if not flights:
        raise DataError(f"{folder}: no extracted flights")
    return flights


def read_stream(path: Path, stream: str) -> pd.DataFrame:
    """One extracted stream's table, with its clocks and the columns the extract stage writes.

    Raises:
        DataError: a file that is not a readable parquet table (cut short, say), or a column missing.
    """
    try:
        table = pd.read_parquet(path)
    except Exception as e:  # pyarrow raises several types for a damaged file
        raise DataError(f"{path}: not a readable parquet file ({type(e).__name__}: {str(e).splitlines()[0][:200]}); "
                        "rerun the extract stage") from None
    missing = [c for c in ("t_recv", "t_src", *STREAM_COLUMNS.get(stream, ())) if c not in table.columns]
    if missing:
        raise DataError(f"{path}: the {stream} stream lacks column(s) {', '.join(map(repr, missing))}; rerun the "
                        "extract stage")
    return table


def sync_folder(extract_dir: Path, out_dir: Path, report_dir: Path, cfg: SyncConfig) -> list[dict]:
    """Synchronise every extracted flight; writes ``<flight>.parquet`` and ``sync.json``/``sync.md``.

    The motor telemetry's lag is a property of the rig: it is estimated once per recording
    session (the ``<date>`` of the flights' names) from the sharp thrust transients of all its
    flights, and that one value is applied to each; every flight's own estimate is reported
    beside it.
    """
    flights = extracted_flights(extract_dir)
    tables, evidence = {}, {}
    for d in tqdm(flights, desc="motor lag", unit="flight", disable=None):
        tables[d.name] = {}
        for stream in STREAMS:
            f = d / f"{stream}.parquet"
            if not f.exists():
                raise DataError(f"{f}: missing (the {stream} stream was not extracted)")
            tables[d.name][stream] = read_stream(f, stream)
        for stream in OPTIONAL_STREAMS:
            if (d / f"{stream}.parquet").exists():
                tables[d.name][stream] = read_stream(d / f"{stream}.parquet", stream)
        t = tables[d.name]
        evidence[d.name] = motor_lag_evidence(str(d), t["imu"], t["motors"], cfg, odom=t["odom"],
                                              setpoint=setpoint_on_stm(t["setpoint"], *onboard_clock(t["odom"], t["imu"])))
    sessions: dict[str, list[str]] = {}
    for name in tables:
        sessions.setdefault(session_of(name), []).append(name)
    lags = {s: motor_lag_estimate([evidence[n] for n in names], cfg) for s, names in sessions.items()}
    reports = []
    with atomic_dir(out_dir, inputs=[extract_dir]) as tmp:
        for d in tqdm(flights, desc="sync", unit="flight", disable=None):
            session = session_of(d.name)
            synced, rep = sync_flight(str(d), tables[d.name], cfg, motor_lag=lags[session])
            rep["flight"] = d.name
            rep["session"] = session
            rep["session_flights"] = len(sessions[session])
            check_finite(synced, f"{d}: synchronised flight")
            synced.to_parquet(tmp / f"{d.name}.parquet", index=False)
            reports.append(rep)
    write_json(Path(report_dir) / "sync.json", reports)
    with atomic_file(Path(report_dir) / "sync.md") as f:
        f.write_text(_sync_markdown(reports))
    return reports


def _ms(v) -> str:
    return "–" if v is None else f"{1000 * v:.1f}"


def _sync_markdown(reports: list[dict]) -> str:
    lines = [
        "# Synchronisation",
        "",
        "Estimated clock relations and lags per flight, and the share of samples each stream",
        "missed (lost packets, dropouts, missed motor readings; filled by the nearest measurement).",
        "",
        "The motor lag applied is the session's, with the host's setpoints as instruments: the lag whose",
        "fit of `a_z`'s moments against the instrument (the thrust the setpoints ask for) by the recorded",
        "sum of squared rotor speeds and the body-z velocity explains most, over all the session's flights",
        "(in closed loop the rotors answer the thrust disturbances a few tens of milliseconds late, which",
        "pulls a plain correlation towards zero lag; the setpoints do not answer them). Its 95 % interval",
        "is a jackknife over blocks (`preprocess.sync.lag_block`); `motor_lag_method` in `sync.json` says which estimator ran. Each",
        "flight's own estimate (around its own sharp thrust transients, interval over them) stands beside it.",
        "",
        "| flight | samples | mocap→STM32 offset [s] | motor lag applied [ms] (95 % interval) | flight's own [ms] (95 % interval, transients) | STM32 drift [ppm] | missing (odom/imu/motors/mocap) | warnings |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in reports:
        m = r["missing"]
        motors = np.mean([m[f"m{i}"] for i in range(1, 5)])
        lo, hi = r["motor_lag_interval"]
        own = r["motor_lag_flight"]
        own_iv = r["motor_lag_flight_interval"] or (None, None)
        lines.append(
            f"| {r['flight']} | {r['samples']} | {r['mocap_to_stm_offset']:.4f} | "
            f"{_ms(r['motor_lag'])} ({_ms(lo)} to {_ms(hi)}) | "
            + (f"{_ms(own)} ({_ms(own_iv[0])} to {_ms(own_iv[1])}, {r['motor_lag_flight_events']}) | " if own is not None
               else "no sharp transient | ")
            + f"{-1e6 * r['stm_drift']:.1f} | {m['odom']:.1%} / {m['imu']:.1%} / {motors:.1%} / {m['mocap']:.1%} | "
            f"{'; '.join(r['warnings']) or '-'} |"
        )
    return "\n".join(lines) + "\n"
