"""The rig's logs -> the product's streams, one table per stream as the extract stage writes them
for a bag (``t_recv`` host time, ``t_src`` source time, values in SI units).

The authors merged every stream of a flight onto one 100 Hz grid ``t``, holding a stream's last
message where no new one had arrived. Each stream is read back as the grid rows where its message
is new (its host stamp advances, or, for the motion capture, which has no stamp of its own, its
position changes), with ``t`` as its source time and its host stamp as the receive time; the
product's own sync then aligns the clocks and the motor lag and resamples, and its filter fills
the held samples as lost packets.

The rules for what the logs hold besides clean readings, each counted in the flight's report:

- ``alias``: a column spelt otherwise in some logs (``torch_yaw``) is read under its name.
- ``yaw_torque_copy``: a logged yaw torque that is the thrust command again (correlation above
  0.99) is no yaw torque; it is left out.
- ``missed``: a reading that is NaN is a missed message of its stream (a missed motor reading
  is a missing value the sync marks; any other stream drops the row).
- ``spike``: an eRPM above ``max_erpm`` is a glitch, not a rotor speed: a missed reading.
- ``segment``: the flight is the trajectory phase of the reference while the vehicle flies (the
  longest run of ``is_flying``): after the take-off phase, which holds the reference's
  horizontal position where the vehicle took off, and before the landing phase, which holds it
  where the vehicle lands while the height descends. The host's setpoint stream is the
  reference inside it and zero outside, stamped by the host, as on the rig.
- ``incomplete``: a log that ends before its reference lands (no landing phase) is left out
  unless ``keep_incomplete``.
- ``accel_frame``: the logged ``ax ay az`` are the specific force in the configured frame
  (``world``: rotated by the attitude); the reader checks the frame against the data (a
  quadrotor's specific force lies along its thrust axis, so in the body frame it has the
  smaller lateral part) and writes the body frame's.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from nanosysid.consistency import Columns, Expect, check as check_consistency
from nanosysid.dataio import SAMPLE_PERIOD, PERIOD_TOL, atomic_dir, check_finite, json_text, parse_flight_name
from nanosysid.errors import ConfigError, DataError

__all__ = ["LogSpec", "REQUIRED", "read_log", "log_streams", "extract_logs", "trajectory_segment", "accel_frame_check"]

log = logging.getLogger(__name__)

REQUIRED = [
    "t", "x", "y", "z", "qx", "qy", "qz", "qw", "vx", "vy", "vz", "wx", "wy", "wz", "ros_timestamp_x",
    "x_mocap", "y_mocap", "z_mocap",
    "m1_erpm", "m2_erpm", "m3_erpm", "m4_erpm", "ros_timestamp_y",
    "ax", "ay", "az", "ros_timestamp",
    "x_r", "y_r", "z_r", "yaw_r", "ros_timestamp_r",
    "is_flying",
]
# the controller's stream, carried as extra signals of each flight where the log has them: the
# motor commands (0..1), the controller's thrust and torques (the firmware's units); with the
# battery's voltage (``vbat``, V)
COMMANDS = {"m1_thrust": "cmd_m1", "m2_thrust": "cmd_m2", "m3_thrust": "cmd_m3", "m4_thrust": "cmd_m4",
            "thrust": "cmd_thrust", "torque_roll": "cmd_torque_roll", "torque_pitch": "cmd_torque_pitch",
            "torque_yaw": "cmd_torque_yaw"}
COPY_CORRELATION = 0.99
# what a stream may hold as NaN: a missed motor reading (the sync marks it), the motion capture's
# attitude the logs lack, a flag a log does not carry
MAY_BE_NAN = {"motors": ("m1", "m2", "m3", "m4"), "mocap": ("qx", "qy", "qz", "qw"), "status": ("battery_voltage", "armed"),
              "controller": ("vbat",)}
# a landing lowers the reference's height by at least this much (m) over its phase
LANDING_DROP = 0.1
COMMAND_SLACK = 0.01  # a motor command beyond 0-1 by more than this is no command
FRAMES = ("world", "body")


@dataclass(frozen=True)
class LogSpec:
    """How a rig's logs convert (``rig.logs`` of ``conf/rig/``)."""

    pole_pairs: float
    erpm_unit: float
    max_erpm: float
    accel_frame: str
    flights: dict[str, str]
    aliases: dict[str, str] = field(default_factory=dict)
    keep_incomplete: bool = False
    min_samples: int = 51

    @property
    def rads_per_erpm(self) -> float:
        """Rotor speed (rad/s) per logged eRPM count: mechanical rpm = eRPM / pole pairs."""
        return self.erpm_unit / self.pole_pairs * (2 * np.pi / 60)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any], *, min_samples: int = 51) -> "LogSpec":
        where = "rig.logs"
        for key in ("pole_pairs", "erpm_unit", "max_erpm"):
            v = cfg.get(key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
                raise ConfigError(f"{where}.{key} must be a positive number, got {v!r}")
        if cfg.get("accel_frame") not in FRAMES:
            raise ConfigError(f"{where}.accel_frame must be one of {', '.join(FRAMES)}, got {cfg.get('accel_frame')!r}")
        flights = dict(cfg.get("flights") or {})
        if not flights:
            raise ConfigError(f"{where}.flights: no log is named (log -> flight name)")
        for stem, name in flights.items():
            try:
                parse_flight_name(str(name))
            except ValueError as e:
                raise ConfigError(f"{where}.flights.{stem}: {e}") from None
        twice = sorted({n for n in flights.values() if list(flights.values()).count(n) > 1})
        if twice:
            raise ConfigError(f"{where}.flights: {twice[0]} is the name of two logs")
        return cls(float(cfg["pole_pairs"]), float(cfg["erpm_unit"]), float(cfg["max_erpm"]), str(cfg["accel_frame"]),
                   {str(k): str(v) for k, v in flights.items()}, dict(cfg.get("aliases") or {}),
                   bool(cfg.get("keep_incomplete", False)), int(min_samples))


def read_log(path: Path, aliases: Mapping[str, str]) -> tuple[pd.DataFrame, list[str]]:
    """One log with its aliased columns renamed; the renames made.

    Raises:
        DataError: not a readable parquet file (a truncated one, say), a required column
            missing, a time that is not finite or does not increase.
    """
    path = Path(path)
    try:
        df = pd.read_parquet(path)
    except Exception as e:  # pyarrow raises several types for a damaged file
        raise DataError(f"{path}: not a readable parquet file ({type(e).__name__}: {str(e).splitlines()[0][:200]})") from None
    renamed = [f"{a} -> {b}" for a, b in aliases.items() if a in df.columns and b not in df.columns]
    df = df.rename(columns={a: b for a, b in aliases.items() if a in df.columns and b not in df.columns})
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(repr(c) for c in missing)} (a rig log has "
                        f"{', '.join(REQUIRED)}; rig.logs.aliases maps a column spelt otherwise)")
    for c in [*REQUIRED, *[k for k in (*COMMANDS, "Vbat", "is_armed") if k in df.columns]]:
        if not (pd.api.types.is_numeric_dtype(df[c]) or pd.api.types.is_bool_dtype(df[c])):
            first = df[c].dropna().iloc[0] if df[c].notna().any() else None
            raise DataError(f"{path}: column {c!r} holds {df[c].dtype} values ({first!r}), not numbers or flags")
    t = df["t"].to_numpy(dtype=np.float64)
    if not np.isfinite(t).all():
        i = int(np.argmax(~np.isfinite(t)))
        raise DataError(f"{path}: column 't', row {i}: {t[i]} is not a time")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise DataError(f"{path}: column 't', row {i}: time does not increase ({t[i]!r} after {t[i - 1]!r})")
    return df, renamed


def _new(stamp: np.ndarray) -> np.ndarray:
    """Rows where a stream's message is new: its stamp advances (a NaN stamp is never new)."""
    ok = np.isfinite(stamp)
    prev = np.maximum.accumulate(np.where(ok, stamp, -np.inf))
    return ok & (stamp > np.r_[-np.inf, prev[:-1]])


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def trajectory_segment(df: pd.DataFrame, where: str) -> tuple[int, int, bool]:
    """``(start, stop, complete)``: the rows of the reference's trajectory phase while flying
    (see the module's ``segment`` rule); ``complete`` is False when the log ends before the
    reference's landing phase.

    Raises:
        DataError: the vehicle never flies, or no reference is set while it does.
    """
    flying = df["is_flying"].to_numpy().astype(bool)
    runs = _runs(flying)
    if not runs:
        raise DataError(f"{where}: column 'is_flying' is never set: no flight in this log")
    a, b = max(runs, key=lambda r: r[1] - r[0])
    p = df[["x_r", "y_r", "z_r"]].to_numpy(dtype=np.float64)
    new = _new(df["ros_timestamp_r"].to_numpy(dtype=np.float64))
    rows = np.flatnonzero(new & (np.arange(len(df)) >= a) & (np.arange(len(df)) < b)
                          & np.isfinite(p).all(axis=1) & (np.abs(p).sum(axis=1) > 0))
    if len(rows) < 3:
        raise DataError(f"{where}: columns 'x_r y_r z_r': no reference while the vehicle flies (rows {a} to {b - 1})")
    xy = p[rows, :2]
    moved = np.flatnonzero((xy != xy[0]).any(axis=1))
    first = int(moved[0]) if moved.size else 0
    settled = np.flatnonzero((xy != xy[-1]).any(axis=1))
    last = int(settled[-1]) if settled.size else len(rows) - 1
    landing = p[rows[last + 1:], 2] if last + 1 < len(rows) else np.empty(0)
    complete = landing.size > 1 and landing[0] - landing.min() >= LANDING_DROP
    start = int(rows[first])
    stop = int(rows[last + 1]) if complete else b
    return start, stop, complete


def _lateral_share(body: np.ndarray) -> float:
    """RMS of a body-frame vector's x and y components over the RMS of its size; ``body`` (N, 3)."""
    size = float(np.sqrt(np.mean((body ** 2).sum(1))))
    return float(np.sqrt(np.mean(body[:, 0] ** 2 + body[:, 1] ** 2))) / max(size, 1e-12)


def accel_frame_check(accel: np.ndarray, q: np.ndarray, frame: str, where: str) -> dict:
    """The lateral share of the specific force read in each frame (RMS of the two components
    across the thrust axis over the RMS magnitude); the configured ``frame`` must be the one in
    which it is smaller.

    Raises:
        DataError: the data say the other frame.
    """
    R = Rotation.from_quat(q)
    share = {"body": _lateral_share(accel), "world": _lateral_share(R.inv().apply(accel))}
    other = "body" if frame == "world" else "world"
    if share[other] < share[frame] and frame == "world":
        # a quaternion in w, x, y, z order turns the world's specific force off the thrust axis in
        # either reading; read in that order it lies along it again
        wfirst = _lateral_share(Rotation.from_quat(q[:, [1, 2, 3, 0]]).inv().apply(accel))
        if wfirst < min(share.values()) / 2:
            raise DataError(f"{where}: columns 'qx qy qz qw': the world's specific force turned to the body by this "
                            f"attitude has a lateral part of {share[frame]:.0%} of its size, read as w, x, y, z "
                            f"{wfirst:.0%}; a quadrotor's specific force lies along its thrust axis: the quaternion is "
                            "in w, x, y, z order (the logs' columns are x, y, z, w)")
    if share[other] < share[frame]:
        raise DataError(f"{where}: columns 'ax ay az': read in the {frame} frame, the body's specific force has a "
                        f"lateral part of {share[frame]:.0%} of its size, in the {other} frame {share[other]:.0%}; a "
                        f"quadrotor's specific force lies along its thrust axis, so the logs hold it in the {other} "
                        f"frame: set rig.logs.accel_frame={other}")
    return {"configured": frame, "lateral_share": share}


# the log's columns by group, for the physical consistency check's messages
LOG_COLUMNS = Columns("x, y, z", "vx, vy, vz", "qx, qy, qz, qw", "wx, wy, wz", "ax, ay, az",
                      "m1_erpm..m4_erpm (× rig.logs.erpm_unit / rig.logs.pole_pairs)")
HOST_STAMPS = ("ros_timestamp_x", "ros_timestamp_y", "ros_timestamp", "ros_timestamp_r")


def check_clocks(df: pd.DataFrame, where: str) -> None:
    """The log's grid ``t`` at the benchmark's rate, and each host stamp advancing at ``t``'s pace
    (both in seconds).

    Raises:
        DataError: naming the column, the rate found and the likely unit.
    """
    t = df["t"].to_numpy(dtype=np.float64)
    step = float(np.median(np.diff(t))) if len(t) > 1 else SAMPLE_PERIOD
    if not abs(step / SAMPLE_PERIOD - 1) <= PERIOD_TOL:
        unit = " (t in ms?)" if abs(step / SAMPLE_PERIOD / 1000 - 1) <= PERIOD_TOL else \
            " (t in µs?)" if abs(step / SAMPLE_PERIOD / 1e6 - 1) <= PERIOD_TOL else ""
        raise DataError(f"{where}: column 't': rows {step:.6g} apart; the logs are on a {1 / SAMPLE_PERIOD:g} Hz grid "
                        f"in seconds ({SAMPLE_PERIOD:g} s){unit}")
    for c in HOST_STAMPS:
        s = df[c].to_numpy(dtype=np.float64)
        ok = np.isfinite(s) & np.isfinite(t)
        # a stream holds its last stamp between messages: its pace is read over a second or more
        if len(np.unique(s[ok])) < 10 or t[ok][-1] - t[ok][0] < 1.0:
            continue
        pace = (s[ok][-1] - s[ok][0]) / (t[ok][-1] - t[ok][0])
        if not 0.5 <= pace <= 2.0:
            unit = next((f" (in {u}?)" for u, f in (("ms", 1e3), ("µs", 1e6), ("ns", 1e9))
                         if abs(np.log(pace / f)) < np.log(1.5)), "")
            raise DataError(f"{where}: column {c!r}: the host stamps advance {pace:.4g} times as fast as 't'; both are "
                            f"seconds{unit}")


def log_streams(df: pd.DataFrame, spec: LogSpec, where: str,
                expect: Expect | None = None) -> tuple[dict[str, pd.DataFrame], dict]:
    """The streams of one log (the extract stage's tables) and the report of the rules applied;
    with ``expect`` (the vehicle's mass, k_F, gravity), the flight segment's columns checked
    against each other first (:mod:`nanosysid.consistency`).

    Raises:
        DataError: a clock in another unit, a degenerate quaternion, no flight segment or one
            shorter than ``spec.min_samples``, a stream without any reading, an acceleration
            frame the data contradict, or columns that contradict each other; naming the log and
            the column.
    """
    check_clocks(df, where)
    t = df["t"].to_numpy(dtype=np.float64)
    rules: dict[str, Any] = {}
    start, stop, complete = trajectory_segment(df, where)
    rules["segment"] = {"start": float(t[start]), "stop": float(t[stop - 1]), "samples": int(stop - start),
                        "complete": bool(complete)}
    if stop - start < spec.min_samples:
        raise DataError(f"{where}: the flight segment has {stop - start} samples, fewer than the {spec.min_samples} "
                        "of one window")

    def values(cols):
        return df[cols].to_numpy(dtype=np.float64)

    q = values(["qx", "qy", "qz", "qw"])
    norm = np.linalg.norm(q, axis=1)
    off = np.isfinite(norm) & (np.abs(norm - 1) > 0.1)
    if off.any():
        i = int(np.argmax(off))
        raise DataError(f"{where}: columns 'qx qy qz qw', row {i}: the attitude quaternion has norm {norm[i]:.3g}, not 1")
    missed: dict[str, int] = {}

    def stream(new: np.ndarray, cols: dict[str, np.ndarray], t_recv: np.ndarray, name: str,
               t_src: np.ndarray = t) -> pd.DataFrame:
        vals = np.column_stack([v for k, v in cols.items() if k not in MAY_BE_NAN.get(name, ())] or
                               list(cols.values()))
        ok = np.isfinite(vals).all(axis=1)  # a reading a stream may lack (a log's battery) drops no row
        if name != "motors":
            dropped = int((new & ~ok).sum())
            if dropped:
                missed[name] = dropped
            new = new & ok
        if not new.any():
            raise DataError(f"{where}: the {name} stream has no reading (columns {', '.join(cols)})")
        return pd.DataFrame({"t_recv": t_recv[new], "t_src": t_src[new], **{k: v[new] for k, v in cols.items()}})

    ts_state = df["ros_timestamp_x"].to_numpy(dtype=np.float64)
    ts_motor = df["ros_timestamp_y"].to_numpy(dtype=np.float64)
    ts_accel = df["ros_timestamp"].to_numpy(dtype=np.float64)
    ts_ref = df["ros_timestamp_r"].to_numpy(dtype=np.float64)
    new_state, new_motor, new_accel, new_ref = (_new(s) for s in (ts_state, ts_motor, ts_accel, ts_ref))

    # the attitude each row holds, for the acceleration's frame (rows without one: none to rotate by)
    accel = values(["ax", "ay", "az"])
    good = np.isfinite(q).all(axis=1) & np.isfinite(accel).all(axis=1)
    seg = np.zeros(len(df), bool)
    seg[start:stop] = True
    rules["accel_frame"] = accel_frame_check(accel[good & seg], q[good & seg], spec.accel_frame, where)
    a_body = np.full_like(accel, np.nan)
    a_body[good] = Rotation.from_quat(q[good]).inv().apply(accel[good]) if spec.accel_frame == "world" else accel[good]

    streams: dict[str, pd.DataFrame] = {}
    streams["odom"] = stream(new_state, {c: df[c].to_numpy(dtype=np.float64) for c in
                                         ("x", "y", "z", "qx", "qy", "qz", "qw", "vx", "vy", "vz")}, ts_state, "odom")
    imu_new = new_state | new_accel
    streams["imu"] = stream(imu_new, {"wx": values(["wx"])[:, 0], "wy": values(["wy"])[:, 0], "wz": values(["wz"])[:, 0],
                                      "ax": a_body[:, 0], "ay": a_body[:, 1], "az": a_body[:, 2]},
                            np.where(new_accel, ts_accel, ts_state), "imu")
    # motion capture: no stamp of its own in the logs, a new frame where the position changes
    mc = values(["x_mocap", "y_mocap", "z_mocap"])
    new_mc = np.r_[True, (np.diff(mc, axis=0) != 0).any(axis=1)] & np.isfinite(mc).all(axis=1)
    mocap = stream(new_mc, {"x": mc[:, 0], "y": mc[:, 1], "z": mc[:, 2]}, ts_state, "mocap")
    # the logs carry no motion-capture attitude: the sync takes the onboard estimate's
    streams["mocap"] = mocap.assign(qx=np.nan, qy=np.nan, qz=np.nan, qw=np.nan)

    erpm = values(["m1_erpm", "m2_erpm", "m3_erpm", "m4_erpm"])
    nan_erpm = np.isnan(erpm) & new_motor[:, None]
    spike = (erpm > spec.max_erpm) & new_motor[:, None]
    rads = np.where(spike | ~np.isfinite(erpm), np.nan, erpm) * spec.rads_per_erpm
    streams["motors"] = stream(new_motor, {f"m{i + 1}": rads[:, i] for i in range(4)}, ts_motor, "motors")
    rules["missed_motor_readings"] = {f"m{i + 1}": int(nan_erpm[:, i].sum()) for i in range(4)}
    rules["spike"] = {"count": {f"m{i + 1}": int(spike[:, i].sum()) for i in range(4)},
                      "largest_erpm": float(np.nanmax(np.where(spike, erpm, np.nan))) if spike.any() else None,
                      "max_erpm": spec.max_erpm}
    never = [i for i in range(4) if streams["motors"][f"m{i + 1}"].isna().all()]
    if never:
        i = never[0]
        over = spike[:, i] & new_motor
        if over.any() and not (new_motor & np.isfinite(erpm[:, i]) & ~over).any():
            raise DataError(f"{where}: column 'm{i + 1}_erpm': every reading lies above rig.logs.max_erpm = "
                            f"{spec.max_erpm:g} (median {np.median(erpm[over, i]):.4g}): the eRPM in another unit, or "
                            "a max_erpm too low for these motors")
        raise DataError(f"{where}: column 'm{i + 1}_erpm' has no valid reading: the motor telemetry is unusable")
    if expect is not None and (complete or spec.keep_incomplete):  # a flight left out is not judged
        # the segment's rows that hold every reading (a log holds each stream's last message between them)
        y = values(["x", "y", "z", "vx", "vy", "vz", "qx", "qy", "qz", "qw", "wx", "wy", "wz"])
        rows = seg & np.isfinite(y).all(axis=1) & np.isfinite(a_body).all(axis=1) & np.isfinite(rads).all(axis=1)
        rules["consistency"] = check_consistency(t[rows], rads[rows], y[rows], a_body[rows], expect, where, LOG_COLUMNS)

    # the host's setpoints: the reference inside the flight segment, zero outside (as the rig sends)
    yaw_r = df["yaw_r"].to_numpy(dtype=np.float64)
    if not np.isfinite(yaw_r[seg]).any():
        raise DataError(f"{where}: column 'yaw_r' has no reading in the flight segment: the reference's yaw is unknown "
                        "(a zero in its place would be a reference the vehicle was not given)")
    pr = values(["x_r", "y_r", "z_r"])
    inside = seg[:, None] & np.isfinite(pr)
    streams["setpoint"] = stream(new_ref, {"x": np.where(inside, pr, 0.0)[:, 0], "y": np.where(inside, pr, 0.0)[:, 1],
                                           "z": np.where(inside, pr, 0.0)[:, 2],
                                           "yaw": np.nan_to_num(df["yaw_r"].to_numpy(dtype=np.float64))},
                                 ts_ref, "setpoint", t_src=ts_ref)
    # the flags as the bags' status stream has them; a log without a battery reading leaves it NaN
    flags = {c: df[k].to_numpy(dtype=np.float64) for k, c in (("Vbat", "battery_voltage"), ("is_armed", "armed"),
                                                                ("is_flying", "flying")) if k in df}
    streams["status"] = stream(new_state, flags, ts_state, "status").reindex(
        columns=["t_recv", "t_src", "battery_voltage", "armed", "flying"])

    commands = {v: df[k].to_numpy(dtype=np.float64) for k, v in COMMANDS.items() if k in df}
    if "cmd_torque_yaw" in commands and "cmd_thrust" in commands:
        a, b = commands["cmd_torque_yaw"][seg], commands["cmd_thrust"][seg]
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() > 2 and np.std(a[ok]) > 0 and np.std(b[ok]) > 0 and np.corrcoef(a[ok], b[ok])[0, 1] > COPY_CORRELATION:
            commands.pop("cmd_torque_yaw")
            rules["yaw_torque_copy"] = "the logged yaw torque follows the thrust command (correlation above " \
                                       f"{COPY_CORRELATION}): no yaw torque; left out"
    if "Vbat" in df:
        commands["vbat"] = df["Vbat"].to_numpy(dtype=np.float64)
    for i in range(1, 5):  # the motor commands are a share of full power
        c = commands.get(f"cmd_m{i}")
        if c is not None:
            off = np.isfinite(c) & ((c < -COMMAND_SLACK) | (c > 1 + COMMAND_SLACK))
            if off.any():
                j = int(np.argmax(off))
                raise DataError(f"{where}: column 'm{i}_thrust', row {j}: a motor command of {c[j]:.4g}, outside its "
                                "0-1 scale (a damaged log?)")
    if commands:
        streams["controller"] = stream(new_motor, commands, ts_motor, "controller")
    rules["missed"] = missed
    rules["held"] = {k: float(1 - len(v) / len(df)) for k, v in streams.items()}
    return streams, rules


def extract_logs(raw_dir: str | Path, out_dir: str | Path, spec: LogSpec, expect: Expect | None = None) -> dict:
    """Every log that ``spec.flights`` names (``raw_dir/**/<log>.parquet``) to
    ``out_dir/<flight>/<stream>.parquet``, and ``out_dir/logs.json``: each flight's log and the
    rules applied to it. A flight left out (``incomplete``) is reported there and not written.
    With ``expect``, each log's columns are checked against each other (:func:`log_streams`).

    Raises:
        DataError: a named log missing or two of one name, a bad log (see :func:`log_streams`),
            or no flight left; nothing is written then.
    """
    raw_dir = Path(raw_dir)
    if not raw_dir.is_dir():
        raise DataError(f"{raw_dir}: no such folder of rig logs (the rig_fetch stage writes it)")
    found: dict[str, Path] = {}
    for p in sorted(raw_dir.rglob("*.parquet")):
        if p.stem in found:
            raise DataError(f"{p}: a second log {p.stem} beside {found[p.stem]}; keep one")
        found[p.stem] = p
    missing = [s for s in spec.flights if s not in found]
    if missing:
        raise DataError(f"{raw_dir}: no log {missing[0]}.parquet (rig.logs.flights names {len(spec.flights)} logs, "
                        f"{len(missing)} of them are not there)")
    report: dict[str, Any] = {"format": "nanosysid-rig-logs-1", "flights": {}}
    with atomic_dir(out_dir, inputs=[raw_dir]) as tmp:
        for stem, name in tqdm(spec.flights.items(), desc="logs", unit="log", disable=None):
            df, renamed = read_log(found[stem], spec.aliases)
            streams, rules = log_streams(df, spec, str(found[stem]), expect)
            if renamed:
                rules["alias"] = renamed
            kept = rules["segment"]["complete"] or spec.keep_incomplete
            report["flights"][name] = {"log": stem, "kept": kept, "rules": rules}
            if not rules["segment"]["complete"]:
                log.warning("%s: the log ends %.2f s in, before its reference lands: %s", found[stem],
                            rules["segment"]["stop"], "kept (keep_incomplete)" if kept else "left out")
            if not kept:
                continue
            (tmp / name).mkdir()
            for s, table in streams.items():
                check_finite(table, f"{found[stem]}: stream {s}", allowed=MAY_BE_NAN.get(s, ()))
                table.to_parquet(tmp / name / f"{s}.parquet", index=False)
        if not any(f["kept"] for f in report["flights"].values()):
            raise DataError(f"{raw_dir}: every log was left out; nothing to synchronise")
        (tmp / "logs.json").write_text(json_text(report))
    return report
