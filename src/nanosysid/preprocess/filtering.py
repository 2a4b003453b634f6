"""filter: gap filling and zero-phase low-pass filtering of a synchronised flight.

Each signal group has its own cut-off (the paper's table of filter cut-offs); the filter is
a fourth-order Butterworth run forwards and backwards (``scipy.signal.sosfiltfilt``), so it
adds no phase lag. Quaternions are filtered as rotation vectors: the log map of the rotation
relative to the flight's first attitude, made continuous in sign, filtered component-wise,
and mapped back with the exponential map, so they stay unit quaternions. (A flight whose
attitude turns more than pi away from its first attitude is outside what this handles.)

Samples with no measurement of their own (lost packets, dropouts) are filled by linear
interpolation between the nearest measured samples when the gap is at most ``max_gap``
samples long (in rotation-vector space for the quaternion); longer gaps keep the nearest
measurement that synchronisation put there, and are reported; a gap longer than ``max_hold``
samples is an error naming the signal and the interval.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd
import torch
from scipy.signal import butter, sosfiltfilt
from tqdm.auto import tqdm

from nanosysid import so3
from nanosysid.consistency import Expect, check_flight
from nanosysid.dataio import ACCEL_COLUMNS, INPUT_COLUMNS, Flight, atomic_dir, write_flight_csv, write_json
from nanosysid.errors import DataError
from nanosysid.settings import configured

__all__ = ["FilterConfig", "filter_flight", "filter_folder", "lowpass", "fill_gaps"]

QUAT = ["qx", "qy", "qz", "qw"]
# the columns of a synchronised flight carried into the published CSV as extra signals
EXTRA_PREFIXES = ("cmd_", "vbat")
log = logging.getLogger("nanosysid.filter")


@configured("preprocess/default.yaml", "filter")
class FilterConfig:
    """The filter stage's settings; their defaults and meaning: ``preprocess.filter`` of
    ``conf/preprocess/default.yaml``."""

    rate: float
    order: int
    position: float
    velocity: float
    acceleration: float
    motors: float
    quaternion: float
    max_gap: int
    max_hold: int

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> "FilterConfig":
        return cls(**dict(cfg))


def lowpass(x: np.ndarray, cutoff: float, rate: float, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth low-pass along axis 0."""
    sos = butter(order, cutoff, "lowpass", fs=rate, output="sos")
    return sosfiltfilt(sos, x, axis=0)


def fill_gaps(x: np.ndarray, missing: np.ndarray, max_gap: int) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Linear interpolation over runs of ``missing`` of at most ``max_gap`` samples.

    Returns:
        The filled array and the ``(start, length)`` of the runs left unfilled.
    """
    x = np.array(x, dtype=np.float64, copy=True)
    if not missing.any():
        return x, []
    padded = np.r_[0, missing.astype(int), 0]
    edges = np.flatnonzero(np.diff(padded))
    starts, ends = edges[::2], edges[1::2]
    long_runs = [(int(s), int(e - s)) for s, e in zip(starts, ends) if e - s > max_gap]
    fill = missing.copy()
    for s, n in long_runs:
        fill[s : s + n] = False
    known = ~missing
    if fill.any() and known.sum() >= 2:
        idx = np.arange(len(x))
        cols = x.reshape(len(x), -1)
        for c in range(cols.shape[1]):
            cols[fill, c] = np.interp(idx[fill], idx[known], cols[known, c])
    return x, long_runs


def _quat_to_rotvec(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation vectors of ``q`` relative to ``q[0]``, and ``q[0]``."""
    qt = torch.from_numpy(np.ascontiguousarray(q, dtype=np.float64))
    q0 = qt[:1]
    rel = so3.quat_mul(so3.quat_conj(q0), qt)
    return so3.quat_log(rel).numpy(), q0.numpy()


def _rotvec_to_quat(r: np.ndarray, q0: np.ndarray) -> np.ndarray:
    return so3.quat_mul(torch.from_numpy(q0), so3.quat_exp(torch.from_numpy(np.ascontiguousarray(r)))).numpy()


def filter_flight(name: str, synced: pd.DataFrame, cfg: FilterConfig) -> tuple[Flight, dict]:
    """Fill short gaps and low-pass every signal group of a synchronised flight.

    Returns:
        The flight in the published schema, and a report of the gaps left unfilled.
    """
    groups = {
        "position": (["x", "y", "z"], "miss_position" if "miss_position" in synced else "miss_mocap", cfg.position),
        "velocity": (["vx", "vy", "vz"], "miss_odom", cfg.velocity),
        "rates": (["wx", "wy", "wz"], "miss_imu", cfg.velocity),
        "acceleration": (list(ACCEL_COLUMNS), "miss_imu", cfg.acceleration),
    }
    out: dict[str, np.ndarray] = {}
    left: dict[str, list[tuple[int, int]]] = {}
    for group, (cols, mask, fc) in groups.items():
        x, runs = fill_gaps(synced[cols].to_numpy(), synced[mask].to_numpy(), cfg.max_gap)
        out.update(zip(cols, lowpass(x, fc, cfg.rate, cfg.order).T))
        if runs:
            left[group] = runs
    for i, col in enumerate(INPUT_COLUMNS):
        x, runs = fill_gaps(synced[col].to_numpy(), synced[f"miss_m{i + 1}"].to_numpy(), cfg.max_gap)
        out[col] = lowpass(x, cfg.motors, cfg.rate, cfg.order)
        if runs:
            left[f"motor {i + 1}"] = runs
    r, q0 = _quat_to_rotvec(synced[QUAT].to_numpy())
    # the attitude's own mask where it does not come from the motion capture (the rig's logs)
    r, runs = fill_gaps(r, synced["miss_attitude" if "miss_attitude" in synced else "miss_mocap"].to_numpy(), cfg.max_gap)
    q = _rotvec_to_quat(lowpass(r, cfg.quaternion, cfg.rate, cfg.order), q0)
    out.update(zip(QUAT, q.T))
    if runs:
        left["orientation"] = runs
    t = synced["t"].to_numpy()
    for group, runs in left.items():
        s, n = max(runs, key=lambda r: r[1])
        if n > cfg.max_hold:
            raise DataError(f"{name}: {group} has no measurement from {t[s] - t[0]:.2f} to {t[s + n - 1] - t[0]:.2f} s "
                            f"({n} samples), longer than preprocess.filter.max_hold = {cfg.max_hold}: its held value "
                            "would stand for the signal there; the recording lost that stream")
    flight = Flight(
        name=name,
        t=np.round(t - t[0], 10),
        u=np.column_stack([out[c] for c in INPUT_COLUMNS]),
        y=np.column_stack([out[c] for c in ("x", "y", "z", "vx", "vy", "vz", *QUAT, "wx", "wy", "wz")]),
        extra={c: out[c] for c in ACCEL_COLUMNS},
    )
    if "yaw_ref" in synced and synced["yaw_ref"].to_numpy().any():
        # the yaw setpoint of a calibration flight: a reference, not a measurement, kept as it is
        flight.extra["yaw_ref"] = synced["yaw_ref"].to_numpy().copy()
    for c in synced.columns:
        if c.startswith(EXTRA_PREFIXES):
            # the controller's commands and the battery: signals beside the flight, kept as recorded
            flight.extra[c] = synced[c].to_numpy().copy()
    report = {"flight": name, "gaps_left": {k: [list(g) for g in v] for k, v in left.items()}}
    return flight, report


def filter_folder(sync_dir: Path, out_dir: Path, report_dir: Path, cfg: FilterConfig,
                  expect: Expect | None = None) -> list[dict]:
    """Filter every synchronised flight into ``out_dir/<flight>.csv`` (the published schema); with
    ``expect`` (the vehicle's mass, k_F, gravity), each flight's columns checked against each other
    first (:mod:`nanosysid.consistency`): nothing is written where one breaks a physical law."""
    files = sorted(Path(sync_dir).glob("*.parquet"))
    if not files:
        raise DataError(f"{sync_dir}: no synchronised flights")
    reports = []
    with atomic_dir(out_dir, inputs=[sync_dir]) as tmp:
        for f in tqdm(files, desc="filter", unit="flight", disable=None):
            flight, rep = filter_flight(f.stem, pd.read_parquet(f), cfg)
            if expect is not None:
                check_flight(flight, expect, where=f"{f} (filtered)")
            write_flight_csv(flight, tmp / f"{f.stem}.csv")
            for group, runs in rep["gaps_left"].items():
                log.warning("%s: %s has %d gap(s) longer than %d samples, left unfilled",
                            f.stem, group, len(runs), cfg.max_gap)
            reports.append(rep)
    write_json(Path(report_dir) / "filter.json", reports)
    return reports
