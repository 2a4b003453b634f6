"""The rig's logs and their fetching, damaged or different: each one clear error naming the file,
the column and the problem, with nothing written, or a named repair that the flight's report
counts (a NaN or glitched reading is a missed one)."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from nanosysid.errors import DataError
from nanosysid.rig import fetch as rigfetch
from nanosysid.rig.logs import LogSpec, extract_logs

CLASS = "silent acceptance"

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "rig"
LOG = DATA / "raw" / "square_20251017_run2.parquet"
CONF = yaml.safe_load((ROOT / "conf" / "rig" / "crazyflie-2025-10-17.yaml").read_text())["logs"]
SPEC = LogSpec.from_mapping(dict(CONF, flights={"square_20251017_run2": "square_20251017_run2"}, keep_incomplete=True))


def with_log(tmp_path: Path, edit=None, raw: bytes | None = None) -> Path:
    folder = tmp_path / "raw"
    folder.mkdir()
    if raw is not None:
        (folder / LOG.name).write_bytes(raw)
    else:
        df = pd.read_parquet(LOG)
        (edit(df) if edit else df).to_parquet(folder / LOG.name, index=False)
    return folder


def refused(tmp_path: Path, folder: Path, match: str) -> None:
    out = tmp_path / "extract"
    with pytest.raises(DataError, match=match):
        extract_logs(folder, out, SPEC)
    assert not out.exists(), "a refused log left output behind"


def test_a_truncated_log(tmp_path):
    data = LOG.read_bytes()
    refused(tmp_path, with_log(tmp_path, raw=data[: len(data) // 2]),
            r"square_20251017_run2\.parquet: not a readable parquet file")


@pytest.mark.parametrize("column", ["x_r", "m3_erpm", "is_flying", "ros_timestamp_y"])
def test_a_column_missing(tmp_path, column):
    refused(tmp_path, with_log(tmp_path, lambda df: df.drop(columns=[column])),
            rf"parquet: missing column\(s\) '{column}'")


def test_a_column_renamed_without_an_alias(tmp_path):
    refused(tmp_path, with_log(tmp_path, lambda df: df.rename(columns={"az": "acc_z"})),
            r"parquet: missing column\(s\) 'az' .*rig\.logs\.aliases")


def test_time_that_goes_backwards(tmp_path):
    def edit(df):
        t = df["t"].to_numpy().copy()
        t[200], t[201] = t[201], t[200]
        return df.assign(t=t)

    refused(tmp_path, with_log(tmp_path, edit), r"column 't', row 201: time does not increase")


def test_a_time_that_is_nan(tmp_path):
    refused(tmp_path, with_log(tmp_path, lambda df: df.assign(t=df["t"].where(df.index != 50))),
            r"column 't', row 50: nan is not a time")


def test_a_flight_of_three_samples(tmp_path):
    refused(tmp_path, with_log(tmp_path, lambda df: df.iloc[100:103]), r"(no reference|fewer than the 51)")


def test_a_motor_that_never_reads(tmp_path):
    refused(tmp_path, with_log(tmp_path, lambda df: df.assign(m2_erpm=np.nan)),
            r"column 'm2_erpm' has no valid reading")


def test_a_degenerate_attitude(tmp_path):
    refused(tmp_path, with_log(tmp_path, lambda df: df.assign(qw=df["qw"].where(df.index != 300, 3.0))),
            r"columns 'qx qy qz qw', row 300: the attitude quaternion has norm")


def test_nan_position_readings_are_missed_messages(tmp_path):
    folder = with_log(tmp_path, lambda df: df.assign(x=df["x"].where((df.index < 300) | (df.index >= 305))))
    report = extract_logs(folder, tmp_path / "extract", SPEC)
    odom = pd.read_parquet(tmp_path / "extract" / "square_20251017_run2" / "odom.parquet")
    assert np.isfinite(odom["x"]).all()
    df = pd.read_parquet(LOG)
    stamps = df["ros_timestamp_x"].iloc[300:305]
    new = int((stamps.to_numpy() > np.maximum.accumulate(df["ros_timestamp_x"].to_numpy())[299:304]).sum())
    assert report["flights"]["square_20251017_run2"]["rules"]["missed"] == {"odom": new}


def test_a_spike_in_a_motor_is_a_missed_reading(tmp_path):
    folder = with_log(tmp_path, lambda df: df.assign(m3_erpm=df["m3_erpm"].where(df.index != 400, 5.0e6)))
    report = extract_logs(folder, tmp_path / "extract", SPEC)
    motors = pd.read_parquet(tmp_path / "extract" / "square_20251017_run2" / "motors.parquet")
    assert motors["m3"].max() < 252000 * np.pi / 180
    assert report["flights"]["square_20251017_run2"]["rules"]["spike"]["largest_erpm"] == 5.0e6


def manifest(folder: Path, tmp_path: Path, change: str | None = None) -> Path:
    lines = []
    for p in sorted(folder.rglob("*.parquet")):
        digest = hashlib.sha256(p.read_bytes()).hexdigest()
        if change == p.name:
            digest = digest[::-1]
        lines.append(f"{digest}  {p.relative_to(folder)}  up/{p.name}")
    m = tmp_path / "m.sha256"
    m.write_text("\n".join(lines) + "\n")
    return m


FETCH = dict(repository="/nonexistent/upstream.git", commit="0" * 40)


def local_copy(tmp_path: Path, change: str | None = None) -> tuple[Path, Path]:
    """A local folder holding the fixture's logs, and its manifest (``change``: that file's hash wrong)."""
    local = tmp_path / "local"
    shutil.copytree(DATA / "raw", local / "raw")
    return local, manifest(local, tmp_path, change=change)


def fetch_refused(tmp_path: Path, local: Path, m: Path, match: str) -> None:
    with pytest.raises(DataError, match=match):
        rigfetch.fetch(m, tmp_path / "out", local=local, **FETCH)
    assert not (tmp_path / "out").exists()


def test_a_checksum_that_differs(tmp_path):
    local, m = local_copy(tmp_path, change=LOG.name)
    fetch_refused(tmp_path, local, m, r"square_20251017_run2\.parquet: SHA-256 [0-9a-f]{64}, but the manifest .* "
                                      r"nothing was written")


def test_a_local_folder_missing_a_file(tmp_path):
    local, m = local_copy(tmp_path)
    (local / "raw" / LOG.name).unlink()
    fetch_refused(tmp_path, local, m, r"square_20251017_run2\.parquet: missing \(1 of the manifest's 2 files")


def test_a_local_folder_with_other_flights(tmp_path):
    local, m = local_copy(tmp_path)
    shutil.copy(LOG, local / "raw" / "square_20251018_run1.parquet")
    fetch_refused(tmp_path, local, m, r"square_20251018_run1\.parquet: not in the manifest")


def test_a_log_whose_battery_reading_failed_keeps_its_flight(tmp_path):
    # the battery's voltage is a reading a log may lack: its flight is read without it
    report = extract_logs(with_log(tmp_path, lambda df: df.assign(Vbat=np.nan)), tmp_path / "extract", SPEC)
    status = pd.read_parquet(tmp_path / "extract" / "square_20251017_run2" / "status.parquet")
    assert report["flights"]["square_20251017_run2"]["kept"] and len(status) > 100
    assert status["battery_voltage"].isna().all() and status["flying"].notna().all()


def test_a_reference_without_its_yaw(tmp_path):
    refused(tmp_path, with_log(tmp_path, lambda df: df.assign(yaw_r=np.nan)),
            r"column 'yaw_r' has no reading in the flight segment")


def test_a_flag_written_as_text(tmp_path):
    refused(tmp_path, with_log(tmp_path, lambda df: df.assign(is_flying=df["is_flying"].map(str))),
            r"column 'is_flying' holds (object|str) values \('(True|False)'\), not numbers or flags")


def test_a_motor_command_off_its_scale(tmp_path):
    refused(tmp_path, with_log(tmp_path, lambda df: df.assign(m3_thrust=df["m3_thrust"].where(df.index != 250, 8.2))),
            r"column 'm3_thrust', row 250: a motor command of 8.2, outside its 0-1 scale")


@pytest.mark.parametrize("what", ["a file", "no such folder"])
def test_a_rig_local_that_is_no_folder_is_named_when_upstream_cannot_be_reached(tmp_path, what):
    local = tmp_path / "data"
    if what == "a file":
        local.write_text("not a folder")
    manifest = tmp_path / "SHA256SUMS"
    manifest.write_text(f"{'0' * 64}  raw/a.parquet  raw/a.parquet\n")
    with pytest.raises(DataError, match=rf"rig.local = {local} is {what}.* which cannot be reached"):
        rigfetch.fetch(manifest, tmp_path / "out", local=local, repository=str(tmp_path / "no-repository"),
                       commit="0" * 40)
    assert not (tmp_path / "out").exists()
