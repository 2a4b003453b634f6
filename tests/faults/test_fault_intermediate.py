"""A stage's input that an earlier stage wrote, damaged since (cut short, a column lost, hand-edited):
one line naming the file and what it lacks, nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
import yaml

from nanosysid.errors import DataError
from nanosysid.preprocess.sync import SyncConfig, sync_folder
from nanosysid.report.tables import load_scores
from nanosysid.rig.logs import LogSpec, extract_logs

CLASS = "silent acceptance"

ROOT = Path(__file__).resolve().parents[2]
RIG = yaml.safe_load((ROOT / "conf" / "rig" / "crazyflie-2025-10-17.yaml").read_text())["logs"]


@pytest.fixture(scope="module")
def extracted(tmp_path_factory):
    """The streams of one real flight cut, as the rig extract writes them."""
    out = tmp_path_factory.mktemp("ex") / "extract"
    spec = LogSpec.from_mapping(dict(RIG, flights={"square_20251017_run2": "square_20251017_run2"}, keep_incomplete=True))
    extract_logs(ROOT / "tests" / "data" / "rig" / "raw", out, spec)
    return out


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst / "square_20251017_run2"


@pytest.mark.parametrize("case, spoil, words", [
    ("an imu table cut in half", lambda f: f.write_bytes(f.read_bytes()[: f.stat().st_size // 2]),
     r"imu.parquet: not a readable parquet file"),
    ("an imu table without 'az'", lambda f: pd.read_parquet(f).drop(columns=["az"]).to_parquet(f, index=False),
     r"imu.parquet: the imu stream lacks column\(s\) 'az'; rerun the extract stage"),
])
def test_a_damaged_stream_is_named_by_the_sync(extracted, tmp_path, case, spoil, words):
    flight = _copy(extracted, tmp_path / "extract")
    spoil(flight / "imu.parquet")
    cfg = SyncConfig.from_mapping(dict(yaml.safe_load((ROOT / "conf/preprocess/default.yaml").read_text())["sync"],
                                       position="onboard"))
    with pytest.raises(DataError, match=words):
        sync_folder(tmp_path / "extract", tmp_path / "sync", tmp_path / "reports", cfg)
    assert not (tmp_path / "sync").exists()


def test_scores_cut_short_are_named_by_the_report(tmp_path):
    f = tmp_path / "eval" / "physics" / "scores.json"
    f.parent.mkdir(parents=True)
    f.write_text(json.dumps({"mae": {"p": [0.1]}})[:20])
    with pytest.raises(DataError, match=r"physics/scores.json: not the evaluation's scores \(JSONDecodeError"):
        load_scores(tmp_path / "eval", ["physics"])


def test_a_lag_search_longer_than_the_flight_names_its_setting(extracted, tmp_path):
    cfg = SyncConfig.from_mapping(dict(yaml.safe_load((ROOT / "conf/preprocess/default.yaml").read_text())["sync"],
                                       position="onboard", max_lag=100.0))
    with pytest.raises(DataError, match=r"overlap for \d+(\.\d+)? s, less than twice preprocess.sync.max_lag = 100 s"):
        sync_folder(extracted, tmp_path / "sync", tmp_path / "reports", cfg)
    assert not (tmp_path / "sync").exists()
