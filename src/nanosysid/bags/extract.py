"""extract: one ROS 2 bag -> one table per stream, values in SI units, with both time stamps.

Every table has ``t_recv`` (the bag's receive time, host clock, s) and ``t_src`` (the
message's header stamp, the source's clock, s), sorted by ``t_src``: Wi-Fi packets may arrive
slightly out of order, and the source stamp is the time of the measurement.
"""

from __future__ import annotations

import logging
import math
import zlib
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import pandas as pd
import yaml
from rosbags.highlevel import AnyReader
from tqdm.auto import tqdm

from nanosysid.bags.mcap import check_indexes
from nanosysid.bags.messages import typestore
from nanosysid.dataio import atomic_dir, check_finite
from nanosysid.errors import ConfigError, DataError
from nanosysid.preprocess import STREAM_COLUMNS

__all__ = ["find_bags", "extract_bag", "extract_folder", "check_topics", "check_crc", "STREAM_COLUMNS", "MAX_CLOCK_STEP", "CRC_KEY"]

log = logging.getLogger(__name__)

# Out-of-order delivery delays single messages; a clock that jumps moves every later message.
# The latency t_recv - t_src over a block of this many received messages has a minimum at
# the link's base latency, whatever the jitter, so a step of that minimum is a clock jump.
CLOCK_BLOCK = 5
MAX_CLOCK_STEP = 2.0  # sample periods
# the metadata key (``custom_data``) of a storage file's CRC-32, written by the recorder
CRC_KEY = "nanosysid.crc32."


def _pose(m) -> list[float]:
    p, q = m.pose.position, m.pose.orientation
    return [p.x, p.y, p.z, q.x, q.y, q.z, q.w]


def _odom(m) -> list[float]:
    p, q, v = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist.linear
    return [p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z]


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors ``v`` (N, 3) rotated by the quaternions ``q`` (N, 4, x y z w): body to world."""
    u, w = q[:, :3], q[:, 3:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _imu(m) -> list[float]:
    w, a = m.angular_velocity, m.linear_acceleration
    return [w.x, w.y, w.z, a.x, a.y, a.z]


def _status(m) -> list[float]:
    return [m.battery_voltage, float(m.armed), float(m.flying)]


def _setpoint(m) -> list[float]:
    p, q = m.pose.position, m.pose.orientation
    # the heading of the reference orientation (zero for a position-only setpoint)
    yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
    return [p.x, p.y, p.z, yaw]


_READERS: dict[str, Callable[[Any], list[float]]] = {
    "mocap": _pose, "odom": _odom, "imu": _imu, "status": _status, "setpoint": _setpoint,
}


# the options each stream of a topic map takes, beside ``topic`` and ``type``
_OPTIONS: dict[str, dict[str, Any]] = {
    "odom": {"velocity_frame": ("world", "body")},
    "motors": {"erpm_unit": float, "pole_pairs": float, "invalid": int},
}


def check_topics(topics: Mapping[str, Mapping[str, Any]], where: str = "topic map") -> None:
    """Refuse a topic map with a missing stream, a missing or unknown option or a bad value.

    Raises:
        ConfigError: naming the stream and the option.
    """
    missing = sorted(set(STREAM_COLUMNS) - set(topics))
    if missing:
        raise ConfigError(f"{where}: no entry for the stream(s) {', '.join(missing)}")
    for stream, spec in topics.items():
        if stream not in STREAM_COLUMNS:
            raise ConfigError(f"{where}: unknown stream {stream!r}; the streams are {', '.join(STREAM_COLUMNS)}")
        options = _OPTIONS.get(stream, {})
        for key in ("topic", "type", *(k for k in options if k != "velocity_frame")):
            if key not in spec:
                raise ConfigError(f"{where}: {stream}.{key} is missing")
        for key, value in spec.items():
            if key in ("topic", "type"):
                if not isinstance(value, str) or not value:
                    raise ConfigError(f"{where}: {stream}.{key} must be a name, got {value!r}")
            elif key not in options:
                raise ConfigError(f"{where}: {stream}.{key} is not an option of this stream "
                                  f"(it takes {', '.join(['topic', 'type', *options])})")
            elif isinstance(options[key], tuple):
                if value not in options[key]:
                    raise ConfigError(f"{where}: {stream}.{key} must be one of {', '.join(options[key])}, got {value!r}")
            elif isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or (
                    options[key] is float and value <= 0):
                raise ConfigError(f"{where}: {stream}.{key} must be a {'positive number' if options[key] is float else 'whole number'}, "
                                  f"got {value!r}")


def find_bags(folder: Path) -> list[Path]:
    """ROS 2 bags in a folder: sub-folders holding a ``metadata.yaml``, sorted by name.

    Raises:
        DataError: no bag, or a sub-folder holding bag files but no ``metadata.yaml``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: no such folder of bags")
    for sub in sorted(p for p in folder.iterdir() if p.is_dir()):
        if not (sub / "metadata.yaml").is_file() and any(sub.glob("*.mcap")) | any(sub.glob("*.db3")):
            raise DataError(f"{sub}: a bag without metadata.yaml (rebuild it with `ros2 bag reindex {sub}`)")
    bags = sorted(p.parent for p in folder.glob("*/metadata.yaml"))
    if not bags:
        raise DataError(f"{folder}: no ROS 2 bag (a folder with metadata.yaml) found")
    return bags


def extract_bag(bag: Path, topics: Mapping[str, Mapping[str, Any]]) -> dict[str, pd.DataFrame]:
    """Read the streams of the topic map from one bag.

    Raises:
        DataError: an unreadable bag, a missing or empty topic, a topic of another message type,
            a clock that jumps by more than two sample periods, a repeated source stamp, a NaN,
            a degenerate quaternion or a motor that never gives a valid reading; the message
            names the bag, the topic and the problem.
    """
    check_topics(topics)
    bag = Path(bag)
    check_crc(bag)
    try:
        reader = AnyReader([bag], default_typestore=typestore())
        reader.open()
    except Exception as e:  # rosbags raises several types for damaged files
        raise DataError(f"{bag}: cannot read the bag ({type(e).__name__}: {e})") from None
    try:
        by_topic = {c.topic: c for c in reader.connections}
        conns = {}
        for stream, spec in topics.items():
            c = by_topic.get(spec["topic"])
            if c is None:
                raise DataError(
                    f"{bag}: topic {spec['topic']} ({stream}) not found; the bag has: {', '.join(sorted(by_topic))}"
                )
            if c.msgtype != spec["type"]:
                raise DataError(f"{bag}: topic {spec['topic']} ({stream}) carries {c.msgtype}, "
                                f"but the topic map says {spec['type']}")
            conns[stream] = c
        rows: dict[str, list] = {s: [] for s in topics}
        stream_of = {c.id: s for s, c in conns.items()}
        try:
            for c, t_recv, raw in reader.messages(connections=list(conns.values())):
                s = stream_of[c.id]
                m = reader.deserialize(raw, c.msgtype)
                stamp = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
                values = _motors(m, topics[s]) if s == "motors" else _READERS[s](m)
                rows[s].append((t_recv * 1e-9, stamp, *values))
        except DataError:
            raise
        except Exception as e:
            raise DataError(f"{bag}: the bag is damaged or truncated ({type(e).__name__}: {e})") from None
    finally:
        reader.close()
    return {s: _table(bag, topics[s], s, rows[s]) for s in topics}


def check_crc(bag: Path) -> None:
    """Compare each storage file of a bag with the CRC-32 its metadata records (bags written by
    this project's recorder). Where the metadata records none (a bag from elsewhere), an MCAP
    file's message indexes are checked against its chunks; the chunks' CRCs, where the writer
    set them (this project's recorder does), are checked by the reader.

    Raises:
        DataError: a file whose CRC differs, naming the file and both values.
    """
    try:
        meta = yaml.safe_load((Path(bag) / "metadata.yaml").read_text(encoding="utf-8")) or {}
        custom = (meta.get("rosbag2_bagfile_information") or {}).get("custom_data") or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError, AttributeError) as e:
        raise DataError(f"{bag}/metadata.yaml: cannot read the bag's metadata ({type(e).__name__}: {e})") from None
    checked = set()
    for key, recorded in sorted(custom.items()):
        if not str(key).startswith(CRC_KEY):
            continue
        checked.add(str(key)[len(CRC_KEY):])
        path = Path(bag) / str(key)[len(CRC_KEY):]
        if not path.is_file():
            raise DataError(f"{path}: the bag's file is missing (its metadata records a CRC for it)")
        found = f"{zlib.crc32(path.read_bytes()):08x}"
        if found != str(recorded):
            raise DataError(f"{path}: CRC-32 {found}, but the bag's metadata records {recorded} when it was "
                            "written: the file was damaged or changed since; record it again or restore a copy")
    # without a file CRC, the chunks' own CRCs (checked by the reader) leave the message
    # indexes, which the reader follows, unchecked
    for path in sorted(Path(bag).glob("*.mcap")):
        if path.name not in checked:
            problem = check_indexes(path)
            if problem:
                raise DataError(f"{bag}: the bag is damaged or truncated ({path.name}: {problem}); record it again "
                                "or restore a copy")


def _motors(m, spec: Mapping[str, Any]) -> list[float]:
    counts = np.asarray(m.erpm, dtype=np.float64)
    rads = counts * spec["erpm_unit"] / spec["pole_pairs"] * (2 * np.pi / 60)
    return list(np.where(counts == spec["invalid"], np.nan, rads))  # a missed reading is missing


def _table(bag: Path, spec: Mapping[str, Any], stream: str, rows: list) -> pd.DataFrame:
    topic = spec["topic"]
    where = f"{bag}: topic {topic} ({stream})"
    if not rows:
        raise DataError(f"{where} has no messages")
    cols = ["t_recv", "t_src", *STREAM_COLUMNS[stream]]
    df = pd.DataFrame(rows, columns=cols)
    values = df[cols[2:]].to_numpy()
    # NaN in a motor channel marks a missed reading; anywhere else it is bad data
    bad = np.isnan(values) if stream != "motors" else np.zeros_like(values, bool)
    bad |= np.isinf(values)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise DataError(f"{where}, message {i}: field {cols[2 + j]} is {values[i, j]}")
    if stream == "motors":
        never = [c for c in cols[2:] if df[c].isna().all()]
        if never:
            raise DataError(f"{where}: every reading of {', '.join(never)} is the invalid marker "
                            f"{spec['invalid']}: the motor telemetry is unusable")
    if "qw" in df:
        norm = np.linalg.norm(df[["qx", "qy", "qz", "qw"]].to_numpy(), axis=1)
        off = np.abs(norm - 1.0) > 0.1
        if off.any():
            i = int(np.argmax(off))
            raise DataError(f"{where}, message {i}: the orientation quaternion has norm {norm[i]:.3g}, not 1")
    if spec.get("velocity_frame") == "body":
        v = rotate(df[["qx", "qy", "qz", "qw"]].to_numpy(), df[["vx", "vy", "vz"]].to_numpy())
        df[["vx", "vy", "vz"]] = v
    _check_span(where, df["t_src"].to_numpy(), df["t_recv"].to_numpy())
    _check_clock(where, df["t_src"].to_numpy(), df["t_recv"].to_numpy())
    _check_placement(where, df["t_src"].to_numpy(), df["t_recv"].to_numpy())
    df = df.sort_values("t_src", kind="stable").reset_index(drop=True)
    rep = np.flatnonzero(np.diff(df["t_src"].to_numpy()) == 0)
    if rep.size:
        raise DataError(f"{where}: time stamp {df['t_src'][rep[0] + 1]:.9f} s repeats")
    return df


def _period(t_src: np.ndarray) -> float:
    d = np.diff(np.sort(t_src))
    d = d[d > 0]
    return float(np.median(d)) if d.size else 0.0


# Source stamps that span this many times the receive times' span (or a fraction of it) are
# in another unit or absent: clocks agree to parts per million, jumps are refused one by one.
MAX_SPAN_RATIO = 10.0
_UNITS = {1e3: "milliseconds", 1e6: "microseconds", 1e9: "nanoseconds",
          1e-3: "thousands of seconds", 1e-6: "millions of seconds"}


def _check_span(where: str, t_src: np.ndarray, t_recv: np.ndarray) -> None:
    """Refuse source stamps that do not run at the host's pace: all equal, or in another unit."""
    if len(t_src) < 2:
        return
    span_src, span_recv = float(np.ptp(t_src)), float(np.ptp(t_recv))
    if span_src == 0.0:
        raise DataError(f"{where}: every source time stamp is {t_src[0]:.3f} s, over {len(t_src)} messages received "
                        f"in {span_recv:.3f} s: the source does not stamp its messages")
    if span_recv <= 0.0:
        return
    ratio = span_src / span_recv
    if 1.0 / MAX_SPAN_RATIO <= ratio <= MAX_SPAN_RATIO:
        return
    unit = min(_UNITS, key=lambda f: abs(math.log10(ratio / f)))
    hint = (f": the stamps look like {_UNITS[unit]} read as seconds"
            if abs(math.log10(ratio / unit)) < 0.3 else ": the source's clock does not run in seconds")
    raise DataError(f"{where}: the source time stamps span {span_src:.6g} s while the messages arrived over "
                    f"{span_recv:.3f} s ({ratio:.3g} times as long){hint}")


def _check_placement(where: str, t_src: np.ndarray, t_recv: np.ndarray) -> None:
    """Refuse single messages whose source stamp is out of place: a stamp more than two sample
    periods off the latency of the messages received around it that also lands, once sorted,
    within half a period of another stamp.

    A message delivered late has the same latency excess, but its genuine stamp fills its own
    slot of the source's tick lattice; a wrong stamp crowds a slot that is taken (and at the
    end of a stream no block of later messages shows a jump).
    """
    n = len(t_src)
    if n < 2 * CLOCK_BLOCK + 1:
        return
    period = _period(t_src)
    d = t_recv - t_src
    padded = np.pad(d, CLOCK_BLOCK, mode="reflect")
    local = np.median(np.lib.stride_tricks.sliding_window_view(padded, 2 * CLOCK_BLOCK + 1), axis=1)
    off = np.abs(d - local) > MAX_CLOCK_STEP * period
    if not off.any():
        return
    order = np.argsort(t_src, kind="stable")
    gap = np.diff(t_src[order])
    crowded = np.zeros(n, bool)
    crowded[order[1:]] |= gap < 0.5 * period
    crowded[order[:-1]] |= gap < 0.5 * period
    bad = off & crowded
    if bad.any():
        i = int(np.argmax(bad))
        shift = local[i] - d[i]
        raise DataError(f"{where}, message {i}: its source time stamp lies {abs(shift):.3f} s "
                        f"{'after' if shift > 0 else 'before'} those of the messages received around it, among "
                        f"stamps {period * 1e3:.3g} ms apart that leave it no slot: the stamp is out of place "
                        "(the source's clock jumped for this message)")


def _check_clock(where: str, t_src: np.ndarray, t_recv: np.ndarray) -> None:
    """Refuse a source or receive clock that jumps by more than two sample periods.

    The messages are in receive order; out-of-order delivery, which only ever adds delay to a
    message, is allowed.
    """
    n = len(t_src) // CLOCK_BLOCK * CLOCK_BLOCK
    if n < 2 * CLOCK_BLOCK:
        return
    limit = MAX_CLOCK_STEP * _period(t_src)
    d = t_recv - t_src
    floor = d[:n].reshape(-1, CLOCK_BLOCK).min(axis=1)  # the base latency of each block
    step = np.diff(floor)
    jump = np.abs(step) > limit
    if not jump.any():
        return
    k = int(np.argmax(jump))
    lo = k * CLOCK_BLOCK
    # the first message after the jump: jitter only ever raises a latency, so a rise shows in
    # the floor of the messages from there on, a fall in the message itself
    near = d[lo:lo + 3 * CLOCK_BLOCK]
    if step[k] > 0:
        moved = np.lib.stride_tricks.sliding_window_view(near, CLOCK_BLOCK).min(axis=1) > floor[k] + limit
    else:
        moved = near < floor[k] - limit
    i = lo + int(np.argmax(moved))
    size = abs(step[k])
    if step[k] > 0:
        raise DataError(f"{where}, message {i}: the source time stamp goes backwards by {size:.3f} s "
                        f"(more than {MAX_CLOCK_STEP:g} sample periods): the source's clock jumped")
    raise DataError(f"{where}, message {i}: the receive time goes backwards by {size:.3f} s against the "
                    f"source time stamps (more than {MAX_CLOCK_STEP:g} sample periods): the host's clock "
                    "jumped back or the source's jumped forward")


def extract_folder(bags_dir: Path, out_dir: Path, topics: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Every bag of ``bags_dir`` to ``out_dir/<flight>/<stream>.parquet``."""
    bags = find_bags(bags_dir)
    with atomic_dir(out_dir, inputs=[bags_dir]) as tmp:
        for bag in tqdm(bags, desc="extract", unit="bag", disable=None):
            tables = extract_bag(bag, topics)
            (tmp / bag.name).mkdir()
            for stream, df in tables.items():
                # a motor's NaN is a missed reading, marked so for sync
                check_finite(df, f"{bag}: stream {stream}", allowed=STREAM_COLUMNS["motors"] if stream == "motors" else ())
                df.to_parquet(tmp / bag.name / f"{stream}.parquet", index=False)
    log.info("extract: %d bags from %s", len(bags), bags_dir)
    return [b.name for b in bags]
