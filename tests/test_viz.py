"""Rerun recordings: the same flight and models give the same bytes wherever they are written, and
the file holds what was logged."""

import struct
import subprocess
import sys

import numpy as np
import pytest

from nanosysid.dataio import Flight
from nanosysid.errors import DataError
from nanosysid.viz import rrd
from nanosysid.viz.rerun import kept_of, write_recording

T, H = 120, 10


@pytest.fixture(scope="module")
def flight():
    rng = np.random.default_rng(7)
    q = rng.normal(size=(T, 4))
    y = np.concatenate([np.cumsum(rng.normal(size=(T, 3)), 0) * 0.01, rng.normal(size=(T, 3)),
                        q / np.linalg.norm(q, axis=1, keepdims=True), rng.normal(size=(T, 3))], axis=1)
    return Flight("melon_20250601_run1", 0.01 * np.arange(T), np.full((T, 4), 2000.0), y)


@pytest.fixture(scope="module")
def rollouts(flight):
    windows = np.stack([flight.y[s + 1:s + 1 + H] for s in range(T - H)])  # (T - H, H, 13)
    return {"naive": windows, "physics": windows + 0.01}


def chunks(path):
    """The recording's chunks (``.rrd``): (entity path, static, {column: values}), row ids left out."""
    import rerun.chunk as rc

    out = []
    for chunk in rc.RrdReader(path).store().stream().collect().stream():
        batch = chunk.to_record_batch()
        out.append((chunk.entity_path, chunk.is_static, {f.name: batch.column(i).to_pylist()
                                                         for i, f in enumerate(batch.schema)
                                                         if f.name != "rerun.controls.RowId"}))
    return sorted(out, key=repr)


def test_recording_is_the_same_bytes_wherever_and_whenever_it_is_written(flight, rollouts, tmp_path):
    paths = [tmp_path / d / f"{flight.name}.rrd" for d in ("a", "elsewhere/b")]
    for path in paths:
        path.parent.mkdir(parents=True)
        write_recording(flight, {n: kept_of(r, 20) for n, r in rollouts.items()}, path, verdicts="# verdicts")
    assert paths[0].read_bytes() == paths[1].read_bytes()
    # the stream whole, with its footer (rerun's own `rrd verify` also accepts a cut file)
    data = paths[0].read_bytes()
    rrd.check(data)
    for cut in (data[:-1], data[:len(data) // 2], data[:100], b"RRF2" + bytes(range(256)) * 8):
        with pytest.raises(ValueError):
            rrd.check(cut)
    spoiled = bytearray(data)
    spoiled[-40] ^= 0xFF  # a byte of the footer
    with pytest.raises(ValueError, match="checksum"):
        rrd.check(bytes(spoiled))
    r = subprocess.run([sys.executable, "-m", "rerun_cli", "rrd", "verify", str(paths[0])], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr
    # and it holds the flight: the drone's pose row by row, each model's rollouts from every 20th start
    got = {(entity, static): columns for entity, static, columns in chunks(paths[0])}
    drone = got["/world/drone", False]
    # (rerun stores positions in float32, one list of instances per row)
    assert np.allclose(np.array(drone["Transform3D:translation"])[:, 0], flight.y[:, :3], rtol=1e-6, atol=1e-7)
    assert np.allclose([d.total_seconds() for d in drone["time"]], flight.t - flight.t[0], atol=1e-9)
    strips = got["/world/rollouts/physics", False]["LineStrips3D:strips"]
    assert len(strips) == len(range(0, T - H, 20))
    assert np.allclose(np.array(strips[1][0])[1:], rollouts["physics"][20, :, :3], rtol=1e-6, atol=1e-7)
    assert got["/discovery", True]["TextDocument:text"] == [["# verdicts"]]


def test_canonical_stream_keeps_every_chunk_and_changes_only_ids_and_wall_clock(tmp_path):
    import rerun as rr
    import rerun.blueprint as rrb

    path = tmp_path / "sdk.rrd"
    rec = rr.RecordingStream("app", recording_id="flight", send_properties=False)
    rec.save(path, default_blueprint=rrb.Blueprint(rrb.TimeSeriesView(origin="s")))
    rec.log("note", rr.TextDocument("hello"), static=True)
    rec.send_columns("s", indexes=[rr.TimeColumn("time", duration=np.arange(5.0))],
                     columns=rr.Scalars.columns(scalars=np.arange(5.0) ** 2))
    rec.flush()
    rec.disconnect()
    written = path.read_bytes()
    out = tmp_path / "canonical.rrd"
    out.write_bytes(rrd.with_footer(rrd.canonical(written, "flight")))
    # the data of every chunk, recording and blueprint, as the SDK wrote it
    assert chunks(out) == chunks(path)
    # none of the SDK's ids is left: they hold the time of writing in nanoseconds (2026: about
    # 1.8e18); ours count from one
    import rerun.chunk as rc

    ids = [chunk.id for chunk in rc.RrdReader(out).store().stream().collect().stream()]
    assert ids and all(int(i.removeprefix("chunk_")[:16], 16) < 1000 for i in ids), ids


def test_canonical_refuses_what_is_not_an_rrd_stream():
    with pytest.raises(ValueError, match="not an RRD stream"):
        rrd.canonical(b"PK\x03\x04 a zip file", "flight")


def test_a_stream_cut_short_is_one_error_naming_the_argument(tmp_path):
    import rerun as rr

    rec = rr.RecordingStream("nanosysid-test", recording_id="flight")
    path = tmp_path / "raw.rrd"
    rec.save(path)
    rec.send_columns("/x", indexes=[rr.TimeColumn("t", duration=np.arange(200.0))],
                     columns=rr.Scalars.columns(scalars=np.arange(200.0) ** 2))
    rec.flush()
    rec.disconnect()
    data = path.read_bytes()
    # the messages up to rerun's end message (its footer after it is rebuilt, never read): each is a
    # u64 kind and a u64 length, then its body
    whole = 12
    while True:
        kind, n = struct.unpack_from("<QQ", data, whole)
        whole += 16 + n
        if kind == rrd._END:
            break
    # cut anywhere before that end: in a message's header, in its body (an Arrow chunk's), or between two
    for cut in range(13, whole, 37):
        with pytest.raises(DataError, match=r"rrd.canonical: data is not a whole RRD stream, cut short or damaged"):
            rrd.canonical(data[:cut], "flight")


@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB file system of its own (tmpfs; root only), unmounted after the test."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("a tmpfs cannot be mounted here (not root)")
    yield mnt
    subprocess.run(["umount", str(mnt)], check=True)


def test_a_recording_on_a_full_disk_is_the_disk_full_error_and_leaves_nothing(flight, rollouts, small_disk,
                                                                               monkeypatch):
    """The SDK's file writer stops on a full disk with a log line and leaves a flush waiting;
    the writer gives up after the flush timeout and names the disk as full."""
    import errno

    from nanosysid.viz import rerun as viz_rerun

    monkeypatch.setattr(viz_rerun, "FLUSH_TIMEOUT", 2.0)
    (small_disk / "filler").write_bytes(bytes(60 * 1024))
    path = small_disk / f"{flight.name}.rrd"
    with pytest.raises(OSError) as e:
        write_recording(flight, {n: kept_of(r, 20) for n, r in rollouts.items()}, path)
    assert e.value.errno == errno.ENOSPC and str(path) in str(e.value)
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler"]
