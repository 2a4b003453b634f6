"""The rig's real flights as a data source: fetching against the manifest, the logs read into the
product's streams (units, frames, the named rules) and the product's own sync and filter on a few
seconds cut from two real flights (tests/data/rig, PROVENANCE.md), with no network and no data
folder."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from nanosysid.dataio import read_flight_csv
from nanosysid.errors import ConfigError, DataError
from nanosysid.preprocess.filtering import FilterConfig, filter_folder
from nanosysid.preprocess.sync import SyncConfig, sync_folder
from nanosysid.rig import fetch as rigfetch
from nanosysid.report import rig
from nanosysid.rig.logs import LogSpec, extract_logs, log_streams, read_log, trajectory_segment

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "rig"
CONF = yaml.safe_load((ROOT / "conf" / "rig" / "crazyflie-2025-10-17.yaml").read_text())
FLIGHTS = {"square_20251017_run2": "square_20251017_run2", "multisine_20251017_run4": "chirp_20251017_run4"}


def spec(**change) -> LogSpec:
    c = dict(CONF["logs"], flights=FLIGHTS, keep_incomplete=True)
    c.update(change)
    return LogSpec.from_mapping(c)


@pytest.fixture(scope="module")
def square():
    df, renamed = read_log(DATA / "raw" / "square_20251017_run2.parquet", CONF["logs"]["aliases"])
    return df, renamed


@pytest.fixture(scope="module")
def chirp_streams():
    df, _ = read_log(DATA / "raw" / "multisine_20251017_run4.parquet", CONF["logs"]["aliases"])
    return df, *log_streams(df, spec(), "chirp")


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    """The fixture's two cuts through extract, the product's sync and filter."""
    out = tmp_path_factory.mktemp("rig")
    report = extract_logs(DATA / "raw", out / "extract", spec())
    sync = sync_folder(out / "extract", out / "sync", out / "reports",
                       SyncConfig.from_mapping(dict(yaml.safe_load((ROOT / "conf/preprocess/default.yaml").read_text())["sync"],
                                                    position="onboard")))
    filter_folder(out / "sync", out / "flights", out / "reports", FilterConfig())
    return out, report, sync


# ---- units and frames ------------------------------------------------------------------------

def test_rotor_speed_is_erpm_over_six_pole_pairs(square):
    df, _ = square
    streams, _ = log_streams(df, spec(), "square")
    m = streams["motors"]
    assert spec().rads_per_erpm == pytest.approx(np.pi / 180, rel=1e-15)
    row = df.set_index("t").loc[m["t_src"].iloc[0]]
    # 6 pole pairs: rpm = eRPM / 6, rad/s = rpm * 2 pi / 60 = eRPM * pi / 180
    assert m["m1"].iloc[0] == pytest.approx(row["m1_erpm"] * np.pi / 180, rel=1e-12)
    # hover is near 1700 rad/s for this vehicle (crazyflie-physics-facts: 1590-1720 rad/s)
    assert 1300 < np.nanmedian(m[["m1", "m2", "m3", "m4"]].to_numpy()) < 2100


def test_body_acceleration_matches_the_authors_processed_values(square):
    df, _ = square
    streams, rules = log_streams(df, spec(), "square")
    imu = streams["imu"].set_index("t_src")
    theirs = pd.read_csv(DATA / "processed" / "square_20251017_run2.csv")
    t = df["t"].to_numpy()[theirs["raw_row"].to_numpy() - 150]
    both = np.isin(t, imu.index)
    ours = imu.loc[t[both], ["ax", "ay", "az"]].to_numpy()
    authors = theirs[["ax_body", "ay_body", "az_body"]].to_numpy()[both]
    logged = df.set_index("t").loc[t[both], ["ax", "ay", "az"]].to_numpy()
    # the authors' values are smoothed: ours agree to their smoothing, the logged (world-frame)
    # ones are off by the tilt (the square flies at up to 40 degrees)
    ours_rms = np.sqrt(np.mean((ours - authors) ** 2))
    logged_rms = np.sqrt(np.mean((logged - authors) ** 2))
    assert ours_rms < 0.6 and logged_rms > 3 * ours_rms, (ours_rms, logged_rms)
    # in hover the specific force is g along the body's z axis
    assert np.median(ours[:, 2]) == pytest.approx(9.81, abs=0.6)
    assert rules["accel_frame"]["lateral_share"]["world"] < rules["accel_frame"]["lateral_share"]["body"]


def test_a_frame_the_data_contradict_is_refused(square):
    df, _ = square
    with pytest.raises(DataError, match=r"'ax ay az'.*set rig\.logs\.accel_frame=world"):
        log_streams(df, spec(accel_frame="body"), "square")


# ---- the named rules -------------------------------------------------------------------------

def test_a_glitch_and_nan_readings_become_missed_readings(chirp_streams):
    df, streams, rules = chirp_streams
    m = streams["motors"].set_index("t_src")
    glitch = df.loc[df["m1_erpm"] > 1e6, "t"].to_numpy()
    assert glitch.size == 3  # t = 20.12-20.14 s (PROVENANCE.md)
    assert m.loc[[x for x in glitch if x in m.index], "m1"].isna().all()
    # one count a message: the merged log holds a message over the grid rows it has no new one for
    messages = df.loc[df["m1_erpm"] > 1e6, "ros_timestamp_y"].nunique()
    assert messages == 2 and rules["spike"]["count"]["m1"] == messages
    assert rules["spike"]["largest_erpm"] == 1892800.0
    nan_messages = df.loc[df["m4_erpm"].isna(), "ros_timestamp_y"].nunique()
    assert df["m4_erpm"].isna().sum() == 2 and rules["missed_motor_readings"]["m4"] == nan_messages == 1
    # the other rotors at those instants are real readings
    assert m.loc[[x for x in glitch if x in m.index], ["m2", "m3", "m4"]].notna().all().all()


def test_the_misspelt_yaw_torque_is_renamed_and_left_out_as_a_copy_of_the_thrust(chirp_streams, square):
    _, streams, rules = chirp_streams
    assert square[1] == ["torch_yaw -> torque_yaw"]
    assert "cmd_torque_yaw" not in streams["controller"] and "yaw_torque_copy" in rules
    assert {"cmd_thrust", "cmd_torque_roll", "cmd_m1", "vbat"} <= set(streams["controller"])


def reference_log(n_fly_end: int = 80) -> pd.DataFrame:
    """A hand-made log: on the ground for rows 0-4, take-off rows 5-19 (the reference holds x, y =
    0.1, 0.2 while z rises), the trajectory rows 20-59, landing rows 60-79 (held at 0.3, 0.3 while
    z falls to 0.05), then zero; one reference message a row."""
    n = 90
    x, y, z = np.zeros(n), np.zeros(n), np.zeros(n)
    x[5:20], y[5:20], z[5:20] = 0.1, 0.2, np.linspace(0.05, 0.5, 15)
    x[20:60], y[20:60], z[20:60] = np.linspace(0.0, 1.0, 40), np.linspace(0.5, 0.0, 40), 0.5
    x[60:80], y[60:80], z[60:80] = 0.3, 0.3, np.linspace(0.5, 0.05, 20)
    fly = np.zeros(n, bool)
    fly[5:n_fly_end] = True
    return pd.DataFrame({"t": np.arange(n) * 0.01, "x_r": x, "y_r": y, "z_r": z, "is_flying": fly,
                         "ros_timestamp_r": 100 + np.arange(n) * 0.01})


def test_the_segment_is_the_trajectory_phase_of_the_reference():
    assert trajectory_segment(reference_log(), "log") == (20, 60, True)


def test_a_log_that_ends_before_the_landing_is_incomplete():
    df = reference_log().iloc[:50]
    start, stop, complete = trajectory_segment(df, "log")
    assert (start, stop, complete) == (20, 50, False)


def test_held_reference_rows_are_not_messages():
    df = reference_log()
    # every second row holds the last message (its stamp repeats), as the merged logs do
    df["ros_timestamp_r"] = 100 + (np.arange(len(df)) // 2) * 0.02
    for c in ("x_r", "y_r", "z_r"):
        df[c] = df[c].to_numpy()[np.arange(len(df)) // 2 * 2]
    assert trajectory_segment(df, "log") == (20, 60, True)


def test_the_real_cut_starts_where_the_take_off_hold_ends_and_has_no_landing(square):
    df, _ = square
    start, stop, complete = trajectory_segment(df, "square")
    # the reference leaves the take-off position (0.004, 0.036) for the trajectory's origin at t = 2.40 s
    assert df["t"].iloc[start] == pytest.approx(2.40) and not complete and stop == len(df)


def test_an_incomplete_flight_is_left_out_unless_kept(tmp_path):
    # both cuts end inside their trajectories: left out, nothing is left to synchronise
    with pytest.raises(DataError, match=r"every log was left out"):
        extract_logs(DATA / "raw", tmp_path / "out", spec(keep_incomplete=False))
    assert not (tmp_path / "out").exists()


# ---- through the product's sync and filter ---------------------------------------------------

def test_the_cuts_pass_sync_and_filter_with_their_extra_signals(processed):
    out, report, sync = processed
    assert sorted(report["flights"]) == ["chirp_20251017_run4", "square_20251017_run2"]
    f = read_flight_csv(out / "flights" / "square_20251017_run2.csv", min_rows=51)
    assert {"cmd_m1", "cmd_thrust", "vbat", "ax_body"} <= set(f.extra) and "cmd_torque_yaw" not in f.extra
    assert 3.3 < f.extra["vbat"].min() <= f.extra["vbat"].max() < 4.3
    # the position is the onboard estimate's (the authors' published flights hold it), not the
    # motion capture's, which trails it by about 90 ms in these logs
    df, _ = read_log(DATA / "raw" / "square_20251017_run2.parquet", {})
    synced = pd.read_parquet(out / "sync" / "square_20251017_run2.parquet")
    logged = df.assign(t=np.round(df["t"], 2)).set_index("t").loc[np.round(synced["t"], 2)]
    measured = ~synced["miss_position"].to_numpy()
    assert np.array_equal(synced["x"].to_numpy()[measured], logged["x"].to_numpy()[measured])
    assert np.abs(synced["x"].to_numpy() - logged["x_mocap"].to_numpy()).max() > 0.1
    rep = {r["flight"]: r for r in sync}
    assert rep["square_20251017_run2"]["attitude"].startswith("onboard estimate")
    assert rep["square_20251017_run2"]["motor_lag_source"] == "session"


# ---- fetching --------------------------------------------------------------------------------

def manifest_for(folder: Path, tmp_path: Path, **wrong) -> Path:
    lines = []
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.suffix != ".md":
            rel = str(p.relative_to(folder))
            digest = wrong.get(rel, hashlib.sha256(p.read_bytes()).hexdigest())
            lines.append(f"{digest}  {rel}  upstream/{rel}")
    m = tmp_path / "files.sha256"
    m.write_text("\n".join(lines) + "\n")
    return m


def upstream_repo(tmp_path: Path) -> tuple[Path, str]:
    """A git repository holding the fixture's files under ``upstream/`` at its first commit (a later
    commit changes one, as the authors' later commits moved the logs to Git LFS)."""
    import subprocess

    repo = tmp_path / "upstream.git"
    shutil.copytree(DATA, repo / "upstream", ignore=shutil.ignore_patterns("*.md"))
    git = lambda *a: subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *a], cwd=repo,  # noqa: E731
                                    check=True, capture_output=True, text=True).stdout.strip()
    git("init", "-q")
    git("add", "-A")
    git("commit", "-qm", "logs")
    commit = git("rev-parse", "HEAD")
    (repo / "upstream" / "raw" / "square_20251017_run2.parquet").write_text("version https://git-lfs.github.com/spec/v1\n")
    git("commit", "-qam", "to LFS")
    return repo, commit


def test_a_local_copy_is_fetched_and_checked(tmp_path):
    local = tmp_path / "copy"
    shutil.copytree(DATA, local, ignore=shutil.ignore_patterns("*.md"))
    m = manifest_for(local, tmp_path)
    got = rigfetch.fetch(m, tmp_path / "raw", local=local, repository=str(tmp_path / "nowhere"), commit="0" * 40)
    assert got["source"] == "local"
    for rel, digest in got["files"].items():
        assert hashlib.sha256((tmp_path / "raw" / rel).read_bytes()).hexdigest() == digest


def test_without_a_local_copy_the_files_come_through_dvc_from_the_pinned_commit(tmp_path):
    repo, commit = upstream_repo(tmp_path)
    m = manifest_for(DATA, tmp_path)
    got = rigfetch.fetch(m, tmp_path / "raw", local=tmp_path / "no-copy", repository=str(repo), commit=commit)
    assert got["source"] == "upstream"
    assert (tmp_path / "raw" / "raw" / "square_20251017_run2.parquet").read_bytes() == \
        (DATA / "raw" / "square_20251017_run2.parquet").read_bytes()
    # the later commit's pointer file is not the pinned campaign's: refused, nothing written
    head = __import__("subprocess").run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True).stdout.strip()
    with pytest.raises(DataError, match=r"square_20251017_run2\.parquet: SHA-256 [0-9a-f]{64}, but the manifest"):
        rigfetch.fetch(m, tmp_path / "raw2", local=None, repository=str(repo), commit=head)
    assert not (tmp_path / "raw2").exists()


def test_no_network_and_no_folder_is_one_line_naming_the_repository(tmp_path):
    m = manifest_for(DATA / "raw", tmp_path)
    nowhere = tmp_path / "nowhere.git"
    with pytest.raises(DataError, match=rf"^rig\.local = {re.escape(str(tmp_path / 'no-copy'))} is no such folder .*fetched "
                                        rf"from {re.escape(str(nowhere))} at c{{40}}, which cannot be reached .*set rig\.local"):
        rigfetch.fetch(m, tmp_path / "raw", local=tmp_path / "no-copy", repository=str(nowhere), commit="c" * 40)
    assert not (tmp_path / "raw").exists()
    ok, why = rigfetch.available(m, tmp_path / "raw", local=None, repository=str(nowhere), commit="c" * 40)
    assert not ok and "cannot be reached" in why


def test_a_manifest_line_of_the_wrong_form_is_named(tmp_path):
    m = tmp_path / "bad.sha256"
    m.write_text("abc  raw/a.parquet  up/a.parquet\n")
    with pytest.raises(DataError, match=r"bad\.sha256, line 1: 'abc' is not a SHA-256"):
        rigfetch.read_manifest(m)


def test_the_log_settings_are_checked():
    with pytest.raises(ConfigError, match=r"rig\.logs\.accel_frame must be one of world, body"):
        spec(accel_frame="imu")
    with pytest.raises(ConfigError, match=r"rig\.logs\.flights\.x: flight name 'chirp' is not of the form"):
        spec(flights={"x": "chirp"})
    with pytest.raises(ConfigError, match=r"rig\.logs\.pole_pairs must be a positive number"):
        spec(pole_pairs=0)


# ---- beside the paper and the authors -------------------------------------------------------

def test_the_authors_alignment_is_read_from_their_shifts_by_hand():
    rng = np.random.default_rng(7)
    n = 200
    log = pd.DataFrame({f"m{i}_erpm": 90000 + np.cumsum(rng.normal(0, 800, n)) for i in range(1, 5)})
    for c in ("wx", "wy", "wz"):
        log[c] = np.cumsum(rng.normal(0, 0.3, n))
    rows = np.arange(20, 150)
    # their rows carry an index one off (state at row r + 1), and their rotor speeds were moved 3
    # samples later (the rotor speed of row r + 1 - 3 stands at row r): a lag of -30 ms
    processed = pd.DataFrame({"Unnamed: 0": rows, "lag_samples": 3})
    for i in range(1, 5):
        processed[f"m{i}_rads"] = log[f"m{i}_erpm"].to_numpy()[rows + 1 - 3] * np.pi / 180
    for c in ("wx", "wy", "wz"):
        processed[c] = log[c].to_numpy()[rows + 1]
    a = rig.authors_alignment(log, processed, rads_per_erpm=np.pi / 180)  # 6 pole pairs
    assert (a["state_shift"], a["motor_shift"], a["lag_samples_field"]) == (1, -2, 3)
    assert a["lag"] == pytest.approx(-0.03)


def sync_report(flight, own, lo, hi, rig_lag=-0.0065, rig_iv=(-0.0107, -0.0023)):
    return {"flight": flight, "motor_lag": rig_lag, "motor_lag_interval": list(rig_iv),
            "motor_lag_method": "the setpoints as instruments", "motor_lag_flight": own,
            "motor_lag_flight_interval": [lo, hi], "motor_lag_flight_events": 12}


def test_a_flights_alignment_is_contradicted_only_beyond_half_the_authors_step():
    sync = [sync_report("a", -0.0345, -0.0355, -0.0336), sync_report("b", -0.0042, -0.0051, -0.0033),
            sync_report("c", 0.0200, 0.0150, 0.0250)]
    authors = {f: {"lag": lag, "lag_samples_field": s, "resolution": 0.01}
               for f, lag, s in (("a", -0.03, 3), ("b", 0.0, 0), ("c", 0.0, 0))}
    text, rec = rig.alignment_section(sync, authors)
    # a: -35.5..-33.6 ms meets -30 +- 5 ms; b: -5.1..-3.3 meets 0 +- 5; c: 15..25 misses 0 +- 5
    assert rec["contradicted"] == ["c"]
    assert rec["outside_rig_interval"] == ["a", "c"]
    assert "| a | -34.5 | -35.5 to -33.6 | 12 | -30.0 (3) |" in text


def test_the_results_beside_the_paper_flag_a_row_over_a_quarter_worse():
    from nanosysid.protocol import Scores
    from nanosysid.report.paper import PAPER_RESULTS

    def scores(scale):
        # a flat MAE curve whose sum over h = 1..50 is the paper's SimErr times scale
        return Scores(mae={k: np.full(50, PAPER_RESULTS["lstm"][k][3] * scale[k] / 50) for k in "pvRw"},
                      n_windows=10)

    res = rig.results_beside_paper({"lstm": scores({"p": 1.0, "v": 1.3, "R": 0.9, "w": 1.2})})
    diff = {k: res["rows"]["lstm"][k]["simerr_difference"] for k in "pvRw"}
    assert diff == pytest.approx({"p": 0.0, "v": 0.3, "R": -0.1, "w": 0.2})
    assert res["worse"] == ["lstm"]


def test_the_repro_leaves_out_the_rig_pipeline_without_its_files(tmp_path, monkeypatch, capsys):
    from nanosysid import repro

    params = tmp_path / "params-rig.yaml"
    manifest = tmp_path / "m.sha256"
    manifest.write_text(f"{'0' * 64}  raw/a.parquet  up/a.parquet\n")
    params.write_text(yaml.safe_dump({"rig": {"manifest": str(manifest), "local": str(tmp_path / "nowhere"),
                                              "paths": {"raw": str(tmp_path / "raw")},
                                              "upstream": {"repository": str(tmp_path / "no-repo"),
                                                           "commit": "c" * 40}}}))
    graph = {"split": set(), "rig_fetch": set(), "rig_split": {"rig_fetch"}, "report": {"split", "rig_split"}}
    assert repro._with_rig(graph, params) == {"split": set(), "report": {"split"}}
    assert capsys.readouterr().out.startswith("rig pipeline skipped: no folder at rig.local")
    (tmp_path / "nowhere").mkdir()
    assert repro._with_rig(graph, params) == graph


def test_each_pipelines_stages_are_named_and_guarded_with_their_own_params(monkeypatch):
    from nanosysid.config import load_params
    from nanosysid.guard import claim, declared, stage_name, stage_run

    monkeypatch.chdir(ROOT)  # dvc.yaml names each stage's params file relative to itself
    assert stage_name("stages.sync", "params-rig.yaml") == "rig_sync"
    assert stage_name("stages.sync", None) == stage_name("stages.sync", "elsewhere.yaml") == "sync"
    cfg = load_params([], path="params-rig.yaml")
    layout = declared(cfg, stage="rig_sync")
    assert layout["rig_sync"][1][0] == "processed/rig/sync" and layout["sync@sim"][1][0] == "processed/sync"
    # a rig stage writing over the simulated world's output is refused (before anything is written)
    with stage_run("rig_sync", cfg), pytest.raises(ConfigError, match=r"processed/sync.*the output of stage sync@sim"):
        with claim("processed/sync", "folder"):
            pass  # pragma: no cover
