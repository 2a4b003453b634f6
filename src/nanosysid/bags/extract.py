"""extract: one ROS 2 bag -> one table per stream, values in SI units, with both time stamps.

Every table has ``t_recv`` (the bag's receive time, host clock, s) and ``t_src`` (the
message's header stamp, the source's clock, s), sorted by ``t_src``: Wi-Fi packets may arrive
slightly out of order, and the source stamp is the time of the measurement.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import pandas as pd
from rosbags.highlevel import AnyReader

from nanosysid.errors import DataError
from nanosysid.bags.messages import typestore

__all__ = ["find_bags", "extract_bag", "STREAM_COLUMNS", "MAX_REORDER"]

log = logging.getLogger(__name__)

# a source stamp may fall behind the previous one by this much (s) through out-of-order
# delivery; more than that is a clock that went backwards
MAX_REORDER = 0.5


def _pose(m) -> list[float]:
    p, q = m.pose.position, m.pose.orientation
    return [p.x, p.y, p.z, q.x, q.y, q.z, q.w]


def _odom(m) -> list[float]:
    p, q, v = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist.linear
    return [p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z]


def _imu(m) -> list[float]:
    w, a = m.angular_velocity, m.linear_acceleration
    return [w.x, w.y, w.z, a.x, a.y, a.z]


def _status(m) -> list[float]:
    return [m.battery_voltage, float(m.armed), float(m.flying)]


def _setpoint(m) -> list[float]:
    p = m.pose.position
    return [p.x, p.y, p.z]


STREAM_COLUMNS: dict[str, list[str]] = {
    "mocap": ["x", "y", "z", "qx", "qy", "qz", "qw"],
    "odom": ["x", "y", "z", "qx", "qy", "qz", "qw", "vx", "vy", "vz"],
    "imu": ["wx", "wy", "wz", "ax", "ay", "az"],
    "motors": ["m1", "m2", "m3", "m4"],
    "status": ["battery_voltage", "armed", "flying"],
    "setpoint": ["x", "y", "z"],
}
_READERS: dict[str, Callable[[Any], list[float]]] = {
    "mocap": _pose, "odom": _odom, "imu": _imu, "status": _status, "setpoint": _setpoint,
}


def find_bags(folder: Path) -> list[Path]:
    """ROS 2 bags in a folder: sub-folders holding a ``metadata.yaml``, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: no such folder of bags")
    bags = sorted(p.parent for p in folder.glob("*/metadata.yaml"))
    if not bags:
        raise DataError(f"{folder}: no ROS 2 bag (a folder with metadata.yaml) found")
    return bags


def extract_bag(bag: Path, topics: Mapping[str, Mapping[str, Any]]) -> dict[str, pd.DataFrame]:
    """Read the streams of the topic map from one bag.

    Raises:
        DataError: an unreadable bag, a missing or empty topic, a repeated source stamp or one
            that goes backwards, or a NaN; the message names the bag, the topic and the problem.
    """
    bag = Path(bag)
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
    return {s: _table(bag, topics[s]["topic"], s, rows[s]) for s in topics}


def _motors(m, spec: Mapping[str, Any]) -> list[float]:
    counts = np.asarray(m.erpm, dtype=np.float64)
    rads = counts * spec["erpm_unit"] / spec["pole_pairs"] * (2 * np.pi / 60)
    return list(np.where(counts == spec["invalid"], np.nan, rads))  # a missed reading is missing


def _table(bag: Path, topic: str, stream: str, rows: list) -> pd.DataFrame:
    if not rows:
        raise DataError(f"{bag}: topic {topic} ({stream}) has no messages")
    cols = ["t_recv", "t_src", *STREAM_COLUMNS[stream]]
    df = pd.DataFrame(rows, columns=cols)
    values = df[cols[2:]].to_numpy()
    # NaN in a motor channel marks a missed reading; anywhere else it is bad data
    bad = np.isnan(values) if stream != "motors" else np.zeros_like(values, bool)
    bad |= np.isinf(values)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise DataError(f"{bag}: topic {topic} ({stream}), message {i}: field {cols[2 + j]} is {values[i, j]}")
    d = np.diff(df["t_src"].to_numpy())
    back = d < -MAX_REORDER
    if back.any():
        i = int(np.argmax(back)) + 1
        raise DataError(
            f"{bag}: topic {topic} ({stream}), message {i}: time stamp goes backwards by {-d[i - 1]:.3f} s"
        )
    df = df.sort_values("t_src", kind="stable").reset_index(drop=True)
    rep = np.diff(df["t_src"].to_numpy()) == 0
    if rep.any():
        i = int(np.argmax(rep)) + 1
        raise DataError(f"{bag}: topic {topic} ({stream}): time stamp {df['t_src'][i]:.9f} s repeats")
    return df
