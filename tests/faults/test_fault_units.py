"""A flight whose columns contradict each other (another unit, another convention, a stuck logger)
is refused where it enters, on a user's CSV flights (the split) and on the rig's logs (the rig
extract), naming the column and the likely unit, with nothing written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from nanosysid.dataio import Flight, write_flight_csv
from nanosysid.errors import DataError
from nanosysid.rig.logs import LogSpec, extract_logs
from nanosysid.splitting import split_folder
from test_consistency import EXPECT, _motion

CLASS = "silent acceptance"

ROOT = Path(__file__).resolve().parents[2]
RIG_DATA = ROOT / "tests" / "data" / "rig" / "raw"
RIG = yaml.safe_load((ROOT / "conf" / "rig" / "crazyflie-2025-10-17.yaml").read_text())["logs"]
Y = ["x", "y", "z", "vx", "vy", "vz", "qx", "qy", "qz", "qw", "wx", "wy", "wz"]


def _scale(cols, k):
    def change(df):
        for c in cols:
            df[c] = df[c] * k
    return change


def _wxyz(q):
    def change(df):
        x, y, z, w = (df[c].to_numpy().copy() for c in q)
        df[q[0]], df[q[1]], df[q[2]], df[q[3]] = w, x, y, z  # w, x, y, z written into the x, y, z, w columns
    return change


def _other_frame(vx, vy):
    def change(df):
        a, b = df[vx].to_numpy().copy(), df[vy].to_numpy().copy()
        df[vx], df[vy] = -b, a
    return change


def _stuck(cols):
    def change(df):
        for c in cols:
            df[c] = df[c].iloc[0]
    return change


# (case, the change to the CSV flight's table, the words the refusal must hold)
CSV = [
    ("rotor speeds in rpm", _scale([f"m{i}_rads" for i in range(1, 5)], 30 / np.pi), r"m1_rads\.\.m4_rads.*in rpm"),
    ("rotor speeds a 60th (eRPM per pole pair read as rpm)", _scale([f"m{i}_rads" for i in range(1, 5)], 1 / 60),
     r"m1_rads.*a 60th"),
    ("rotor speeds halved (pole pairs doubled)", _scale([f"m{i}_rads" for i in range(1, 5)], 0.5), r"m1_rads.*pole pairs"),
    ("rotor speeds 60 times", _scale([f"m{i}_rads" for i in range(1, 5)], 60.0), r"m1_rads.*60 times"),
    ("rotor speeds doubled (pole pairs halved)", _scale([f"m{i}_rads" for i in range(1, 5)], 2.0),
     r"m1_rads.*twice the speed: the pole pairs halved"),
    ("positions in cm", _scale(["x", "y", "z"], 100.0), r"x, y, z.*in cm rather than m"),
    ("rotor speeds negated", _scale([f"m{i}_rads" for i in range(1, 5)], -1.0), r"m1_rads.*sign"),
    ("gyro in deg/s", _scale(["wx", "wy", "wz"], 180 / np.pi), r"w[xyz].*deg/s"),
    ("velocities ten times", _scale(["vx", "vy", "vz"], 10.0), r"vx, vy, vz.*ten times too large"),
    ("accelerometer in g", _scale(["ax_body", "ay_body", "az_body"], 1 / 9.81), r"ax_body.*in g"),
    ("positions in mm", _scale(["x", "y", "z"], 1000.0), r"x, y, z.*in mm"),
    ("one position in mm", _scale(["x"], 1000.0), r"'x'.*in mm"),
    ("quaternion in w, x, y, z order", _wxyz(["qx", "qy", "qz", "qw"]), r"qx, qy, qz, qw.*w, x, y, z order"),
    ("velocities in another frame", _other_frame("vx", "vy"), r"'vx' does not follow.*another frame"),
    ("a stuck logger", _stuck(Y), r"stuck logger"),
]


def _flight(name: str, shift: int) -> Flight:
    """The hand-made motion of tests/test_consistency.py, ``shift`` samples on (another flight)."""
    t, u, y, a = _motion(1500 + shift)
    return Flight(name, t[:1500], u[shift:], y[shift:], {"ax_body": a[shift:, 0], "ay_body": a[shift:, 1],
                                                          "az_body": a[shift:, 2]})


@pytest.mark.parametrize("case, change, words", CSV, ids=[c for c, _, _ in CSV])
def test_a_csv_flight_in_another_unit_or_convention_is_refused_by_the_split(tmp_path, case, change, words):
    flights = tmp_path / "flights"
    write_flight_csv(_flight("chirp_20250101_run1", 0), flights / "chirp_20250101_run1.csv")
    bad = flights / "melon_20250101_run1.csv"
    write_flight_csv(_flight("melon_20250101_run1", 37), bad)
    df = pd.read_csv(bad)
    change(df)
    df.to_csv(bad, index=False)
    with pytest.raises(DataError, match=words) as e:
        split_folder(flights, tmp_path / "split", train=["chirp"], test=["melon"], horizon=10, expect=EXPECT)
    assert str(bad) in str(e.value)
    assert not (tmp_path / "split").exists()


# the same mistakes in a rig log's own columns, and its clocks in other units
RIG_CASES = [
    ("eRPM in another unit (×60)", _scale([f"m{i}_erpm" for i in range(1, 5)], 60.0), r"m1_erpm.*max_erpm.*unit"),
    ("eRPM a 60th", _scale([f"m{i}_erpm" for i in range(1, 5)], 1 / 60), r"m1_erpm.*a 60th"),
    ("eRPM negated", _scale([f"m{i}_erpm" for i in range(1, 5)], -1.0), r"m1_erpm.*sign"),
    ("gyro in deg/s", _scale(["wx", "wy", "wz"], 180 / np.pi), r"w[xyz].*deg/s"),
    ("velocities ten times", _scale(["vx", "vy", "vz"], 10.0), r"vx, vy, vz.*ten times too large"),
    ("accelerometer in g", _scale(["ax", "ay", "az"], 1 / 9.81), r"ax, ay, az.*in g"),
    ("positions in mm", _scale(["x", "y", "z"], 1000.0), r"x, y, z.*in mm"),
    ("quaternion in w, x, y, z order", _wxyz(["qx", "qy", "qz", "qw"]), r"qx qy qz qw.*w, x, y, z order"),
    ("velocities in another frame", _other_frame("vx", "vy"), r"another frame"),
    ("the log's time in ms", _scale(["t"], 1000.0), r"column 't'.*t in ms"),
    ("host stamps in ns", _scale(["ros_timestamp_x", "ros_timestamp_y", "ros_timestamp", "ros_timestamp_r"], 1e9),
     r"ros_timestamp.*in ns"),
]


@pytest.mark.parametrize("case, change, words", RIG_CASES, ids=[c for c, _, _ in RIG_CASES])
def test_a_rig_log_in_another_unit_or_convention_is_refused_by_the_rig_extract(tmp_path, case, change, words):
    raw = tmp_path / "raw"
    raw.mkdir()
    df = pd.read_parquet(RIG_DATA / "square_20251017_run2.parquet")
    change(df)
    df.to_parquet(raw / "square_20251017_run2.parquet", index=False)
    spec = LogSpec.from_mapping(dict(RIG, flights={"square_20251017_run2": "square_20251017_run2"}, keep_incomplete=True))
    with pytest.raises(DataError, match=words) as e:
        extract_logs(raw, tmp_path / "extract", spec, EXPECT)
    assert "square_20251017_run2.parquet" in str(e.value)
    assert not (tmp_path / "extract").exists()


# the rig's settings that convert its eRPM, set wrong: the same check names the speeds' level
@pytest.mark.parametrize("change, words", [
    (dict(pole_pairs=12), r"m1_erpm.*times the expected: half the speed: the pole pairs doubled"),
    (dict(erpm_unit=60), r"m1_erpm.*60 times: eRPM units"),
    (dict(max_erpm=1), r"column 'm1_erpm': every reading lies above rig.logs.max_erpm = 1 .*another unit, or a "
                       r"max_erpm too low"),
], ids=["12 pole pairs for 6", "an eRPM unit of 60", "a max_erpm of 1"])
def test_a_rig_setting_that_converts_the_rotor_speeds_wrong_is_named(tmp_path, change, words):
    spec = LogSpec.from_mapping(dict(RIG, flights={"square_20251017_run2": "square_20251017_run2"}, keep_incomplete=True,
                                     **change))
    with pytest.raises(DataError, match=words):
        extract_logs(RIG_DATA, tmp_path / "extract", spec, EXPECT)
    assert not (tmp_path / "extract").exists()


def test_a_csv_flight_with_positions_of_1e300_is_refused_by_the_split(tmp_path):
    flights = tmp_path / "flights"
    write_flight_csv(_flight("chirp_20250101_run1", 0), flights / "chirp_20250101_run1.csv")
    bad = flights / "melon_20250101_run1.csv"
    write_flight_csv(_flight("melon_20250101_run1", 37), bad)
    df = pd.read_csv(bad)
    df.loc[300:, "x"] = 1e300
    df.to_csv(bad, index=False)
    with pytest.raises(DataError, match=r"melon_20250101_run1.csv: column\(s\) 'x' against the velocity's integral"):
        split_folder(flights, tmp_path / "split", train=["chirp"], test=["melon"], horizon=10, expect=EXPECT)
    assert not (tmp_path / "split").exists()
