"""Recordings damaged or read with the wrong settings are refused where they enter (extract,
sync, filter), naming the bag or flight, the stream and the interval, instead of becoming held
values, stopped rotors or rotated velocities in the benchmark."""

from __future__ import annotations

import copy
import dataclasses
import re
import shutil
import zlib

import numpy as np
import pytest

from bagtools import IMU, MOCAP, MOTORS, TOPICS, record, rewrite, shift_stamp, stamp_of
from nanosysid.bags.extract import extract_bag
from nanosysid.preprocess.filtering import FilterConfig, filter_flight
from nanosysid.preprocess.sync import SyncConfig, sync_flight
from nanosysid.errors import DataError

CLASS = "silent acceptance"


def process(path, topics=TOPICS):
    tables = extract_bag(path, topics)
    synced, _ = sync_flight(path.name, tables, SyncConfig())
    return filter_flight(path.name, synced, FilterConfig())


def test_the_intact_bag_passes(bag):
    flight, _ = process(bag)
    assert np.isfinite(flight.y).all()


# ---- bits changed after recording: the recorder's CRC ----------------------------------------

@pytest.mark.parametrize("at", [0.02, 0.25, 0.5, 0.75, 0.98])
def test_a_flipped_bit_anywhere_in_the_bag_is_refused_by_its_crc(bag, tmp_path, at):
    dst = tmp_path / bag.name
    shutil.copytree(bag, dst)
    mcap = next(dst.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    data[int(at * len(data))] ^= 0x04
    mcap.write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"\.mcap: CRC-32 [0-9a-f]{8}, but the bag's metadata records [0-9a-f]{8}"):
        extract_bag(dst, TOPICS)


def test_a_crc_edited_in_the_metadata_is_refused(bag, tmp_path):
    dst = tmp_path / bag.name
    shutil.copytree(bag, dst)
    meta = dst / "metadata.yaml"
    text = meta.read_text()
    crc = re.search(r"nanosysid\.crc32\.\S+: '?([0-9a-f]{8})", text).group(1)
    meta.write_text(text.replace(crc, f"{int(crc, 16) ^ 1:08x}"))
    with pytest.raises(DataError, match=rf"CRC-32 {crc}, but the bag's metadata records"):
        extract_bag(dst, TOPICS)


def test_a_bag_file_gone_from_its_folder_is_named(bag, tmp_path):
    dst = tmp_path / bag.name
    shutil.copytree(bag, dst)
    next(dst.glob("*.mcap")).unlink()
    with pytest.raises(DataError, match=r"\.mcap: the bag's file is missing"):
        extract_bag(dst, TOPICS)


def test_a_flipped_bit_is_refused_by_the_chunk_crcs_when_the_metadata_lost_its_crc(bag, tmp_path):
    """A bag whose metadata no longer records the file's CRC still carries a CRC-32 of each
    chunk's records, computed here with zlib over the zstd-decompressed records."""
    dst = tmp_path / bag.name
    shutil.copytree(bag, dst)
    meta = dst / "metadata.yaml"
    meta.write_text(re.sub(r"\n\s*nanosysid\.crc32\.\S+: '?[0-9a-f]{8}'?", "", meta.read_text()))
    mcap = next(dst.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    # the first chunk record (opcode 0x06) after the 8-byte magic and the header record
    at = data.index(b"\x06", 8)
    while int.from_bytes(data[at + 1:at + 9], "little") > len(data):
        at = data.index(b"\x06", at + 1)
    body = at + 9
    n_name = int.from_bytes(data[body + 28:body + 32], "little")
    start = body + 32 + n_name + 8
    records = bytes(data[start:start + int.from_bytes(data[start - 8:start], "little")])
    try:
        from compression import zstd
    except ImportError:
        from backports import zstd
    assert int.from_bytes(data[body + 24:body + 28], "little") == zlib.crc32(zstd.decompress(records))
    extract_bag(dst, TOPICS)  # without the metadata's CRC, an intact bag still passes
    data[len(data) // 3] ^= 0x04
    mcap.write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"the bag is damaged or truncated"):
        extract_bag(dst, TOPICS)


# ---- streams lost for long stretches: coverage and held values ------------------------------

def during(topic_name, start, stop, edit):
    """A change applying ``edit(msg) -> msg | None`` to the messages of one topic stamped ``start``
    to ``stop`` s after its first (None drops the message)."""
    first = {}

    def change(topic, m, t):
        if topic == topic_name:
            t0 = first.setdefault("t", stamp_of(m))
            if start <= stamp_of(m) - t0 < stop:
                m = edit(m)
                return None if m is None else (m, t)
        return m, t
    return change


def lose(topic_name, start, stop):
    return during(topic_name, start, stop, lambda m: None)


LOSSES = [
    ("imu lost for most of the flight", IMU, 1.0, 7.5, r"stream imu misses \d+% of the flight's samples \(its longest gap"),
    ("motors lost for most of the flight", MOTORS, 0.5, 7.0, r"stream m1 misses \d+% of the flight's samples"),
    ("mocap lost for most of the flight", MOCAP, 2.0, 7.0, r"stream mocap misses \d+% of the flight's samples"),
    ("odometry lost for most of the flight", TOPICS["odom"]["topic"], 0.5, 6.5, r"stream odom misses \d+% of the flight"),
    ("imu lost for 0.6 s", IMU, 3.0, 3.6, r"rates has no measurement from \d+\.\d\d to \d+\.\d\d s \(\d+ samples\), longer "
                                          r"than preprocess\.filter\.max_hold = 30"),
    ("mocap lost for 0.8 s", MOCAP, 4.0, 4.8, r"position has no measurement from .* longer than preprocess\.filter\.max_hold"),
    ("motors lost for 1 s", MOTORS, 2.0, 3.0, r"motor 1 has no measurement from .* longer than preprocess\.filter\.max_hold"),
]


@pytest.mark.parametrize("case,topic,start,stop,words", LOSSES, ids=[c[0] for c in LOSSES])
def test_a_stream_lost_for_long_is_an_error_naming_it_and_the_interval(bag, tmp_path, case, topic, start, stop, words):
    dst = rewrite(bag, tmp_path / bag.name, lose(topic, start, stop))
    with pytest.raises(DataError, match=words):
        process(dst)


# ---- readings no flying vehicle gives ------------------------------------------------------

def motor_zero(index, start, stop):
    def zero(m):
        erpm = m.erpm.copy()
        erpm[index] = 0
        return dataclasses.replace(m, erpm=erpm)
    return during(MOTORS, start, stop, zero)


@pytest.mark.parametrize("index,start,stop", [(0, 3.0, 3.5), (2, 2.0, 2.1), (3, 0.0, 12.0), (1, 6.0, 6.05)],
                         ids=["m1 at 0 for 0.5 s", "m3 at 0 for 0.1 s", "m4 at 0 throughout", "m2 at 0 for 50 ms"])
def test_a_rotor_at_zero_in_flight_is_refused(bag, tmp_path, index, start, stop):
    dst = rewrite(bag, tmp_path / bag.name, motor_zero(index, start, stop))
    with pytest.raises(DataError, match=rf"motor m{index + 1} reads 0 rad/s from \d+\.\d\d to \d+\.\d\d s while the "
                                        r"others turn at about \d+ rad/s: a rotor cannot stop in flight"):
        process(dst)


def motor_scaled(index, factor):
    def scale(m):
        erpm = m.erpm.copy()
        erpm[index] = erpm[index] * factor
        return dataclasses.replace(m, erpm=erpm)
    return during(MOTORS, 0.0, 1e9, scale)


@pytest.mark.parametrize("index,factor", [(2, 0.5), (0, 1.3)], ids=["m3 at half its speed", "m1 at 1.3 times"])
def test_a_rotor_read_at_another_scale_all_flight_is_refused(bag, tmp_path, index, factor):
    """One rotor's telemetry at another scale throughout (another unit, a gain): the four rotors
    of a flying quadrotor turn within a few per cent of each other, so the ratio of its median
    to the four's is the factor, to the few per cent the unscaled rotors differ by."""
    dst = rewrite(bag, tmp_path / bag.name, motor_scaled(index, factor))
    with pytest.raises(DataError, match=rf"motor m{index + 1} reads (\d\.\d\d) times the four rotors' median speed "
                                        r"over the flight \(\d+ against \d+ rad/s\)") as e:
        process(dst)
    reported = float(re.search(r"reads (\d\.\d\d) times", str(e.value)).group(1))
    assert reported == pytest.approx(factor, rel=0.03)


def test_a_rotor_reading_zero_once_is_a_glitch_not_a_stop(bag, tmp_path):
    dst = rewrite(bag, tmp_path / bag.name, motor_zero(1, 3.0, 3.015))
    process(dst)


# ---- clocks that step ------------------------------------------------------------------------

@pytest.mark.parametrize("step", [0.003, -0.002, 0.0045], ids=["+3 ms", "-2 ms", "+4.5 ms"])
def test_an_imu_clock_that_steps_by_part_of_a_sample_is_refused(bag, tmp_path, step):
    """The IMU's and the odometry's stamps share the onboard clock's ticks; from 4 s on the IMU's
    are moved by ``step``: its gyro would sit ``step`` off every other signal without a word."""
    dst = rewrite(bag, tmp_path / bag.name, during(IMU, 4.0, 1e9, lambda m: shift_stamp(m, step)))
    with pytest.raises(DataError, match=r"from (\d+\.\d\d) s the IMU's stamps are " + re.escape(f"{step * 1e3:+.1f}")
                                        + r" ms off the odometry's, whose clock ticks they share elsewhere in the flight") as e:
        process(dst)
    assert float(re.search(r"from (\d+\.\d\d) s", str(e.value)).group(1)) == pytest.approx(4.0, abs=0.6)


@pytest.mark.parametrize("step", [0.01, 0.02], ids=["+1 sample", "+2 samples"])
def test_an_imu_clock_that_steps_by_whole_samples_is_refused(bag, tmp_path, step):
    """A step of whole 10 ms ticks leaves the IMU's stamps on the odometry's ticks, which the
    case above reads; the host received the messages when it did, so from 4 s on the IMU's
    stamps stand ``step`` off the odometry's against the receive times. (A step back by whole
    ticks repeats a stamp, and one of more than two ticks forward outruns the receive times:
    extract refuses both.)"""
    dst = rewrite(bag, tmp_path / bag.name, during(IMU, 4.0, 1e9, lambda m: shift_stamp(m, step)))
    with pytest.raises(DataError, match=r"from about (\d+) s the IMU's stamps are ([-+]\d+\.\d) ms off the odometry's "
                                        r"against the host's receive times \(([-+]\d\.\d) samples\), on ticks the two "
                                        "share: the IMU's clock stepped by whole ticks") as e:
        process(dst)
    at, ms, samples = re.search(r"from about (\d+) s .* are ([-+]\d+\.\d) ms .* \(([-+]\d\.\d) samples\)",
                                str(e.value)).groups()
    # the least delay of a second of messages is within a fraction of a millisecond of the link's
    # shortest transit; the bin of one second the step falls in is judged on either side
    assert float(ms) == pytest.approx(step * 1e3, abs=0.5) and float(samples) == pytest.approx(step / 0.01, abs=0.1)
    assert 3 <= int(at) <= 6


# ---- settings that are not the recording's --------------------------------------------------

def odom_frame(frame):
    topics = copy.deepcopy(TOPICS)
    topics["odom"]["velocity_frame"] = frame
    return topics


@pytest.mark.parametrize("recorded,read", [("body", "world"), ("world", "body")])
def test_odometry_read_in_the_wrong_frame_is_refused(raw, tmp_path, recorded, read):
    path = tmp_path / "melon_20250601_run1"
    record(raw, path, topics=odom_frame(recorded))
    with pytest.raises(DataError, match=rf"read as {recorded}-frame values: preprocess\.topics\.odom\.velocity_frame "
                                        "does not match the recording"):
        process(path, odom_frame(read))
    process(path, odom_frame(recorded))  # read as recorded, it passes


@pytest.mark.parametrize("key,value", [("pole_pairs", 0), ("erpm_unit", -100), ("velocity_frame", "sideways")])
def test_a_bad_topic_map_option_is_refused_before_reading(bag, key, value):
    topics = copy.deepcopy(TOPICS)
    topics["odom" if key == "velocity_frame" else "motors"][key] = value
    with pytest.raises(Exception) as e:
        extract_bag(bag, topics)
    assert re.search(rf"\.{key} must be", str(e.value)), str(e.value)
