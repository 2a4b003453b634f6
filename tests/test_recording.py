"""Recordings and the data pipeline: bags, extraction, synchronisation, filtering, bad input."""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from bagtools import CFG, IMU, MOCAP, TOPICS, nth_message, record, rewrite, shift_stamp, stamp_of
from rosbags.highlevel import AnyReader

from nanosysid import so3
from nanosysid.bags.extract import extract_bag
from nanosysid.preprocess.filtering import FilterConfig, fill_gaps, filter_flight, lowpass
from nanosysid.bags.messages import typestore
from nanosysid.bags.recorder import RecorderConfig, firmware_lowpass, record_flight
from nanosysid.sim import FlightSpec
from nanosysid.sim.simulator import flights_from_record, simulate_raw
from nanosysid.preprocess.lag import motor_lag_estimate, motor_lag_evidence
from nanosysid.preprocess.sync import SyncConfig, sync_flight
from nanosysid.errors import DataError
from nanosysid.vehicle import Vehicle
from nanosysid.bags.extract import extract_folder

ROOT = Path(__file__).resolve().parents[1]



def process(bag_path):
    tables = extract_bag(bag_path, TOPICS)
    synced, report = sync_flight(bag_path.name, tables, SyncConfig())
    flight, _ = filter_flight(bag_path.name, synced, FilterConfig())
    return tables, synced, report, flight


def test_bag_holds_every_stream_with_its_message_type(bag):
    with AnyReader([bag], default_typestore=typestore()) as r:
        got = {c.topic: (c.msgtype, c.msgcount) for c in r.connections}
    for spec in TOPICS.values():
        assert got[spec["topic"]][0] == spec["type"] and got[spec["topic"]][1] > 0
    # mocap at 120 Hz and the onboard streams at 100 Hz, less a few percent of lost packets
    n_mocap, n_imu = got[TOPICS["mocap"]["topic"]][1], got[TOPICS["imu"]["topic"]][1]
    assert 1.1 < n_mocap / n_imu < 1.35


def test_extract_converts_to_si_units(bag, raw):
    tables = extract_bag(bag, TOPICS)
    motors = tables["motors"][["m1", "m2", "m3", "m4"]].to_numpy()
    assert np.isnan(motors).any()  # missed readings (the invalid marker) are missing, not numbers
    assert abs(np.nanmedian(motors) - Vehicle().hover_speed) < 100  # rad/s around hover
    assert abs(tables["imu"]["az"].median() - 9.81) < 1.0  # specific force in m/s^2
    assert np.all(np.diff(tables["odom"]["t_src"]) > 0)  # sorted by the source clock


def test_the_imu_reads_through_a_filter_that_delays_a_slow_signal_as_the_analogue_one():
    # a second-order Butterworth low-pass at fc delays a signal far below fc by sqrt(2) / (2 pi fc)
    # (the analogue filter's group delay at 0 Hz) and passes it whole
    t = np.arange(0.0, 4.0, 0.002)
    fc, f = 30.0, 0.5
    y, delay = firmware_lowpass(t, np.sin(2 * np.pi * f * t)[:, None], fc)
    analogue = np.sqrt(2) / (2 * np.pi * fc)
    assert abs(delay - analogue) < 0.02 * analogue
    late = t > 1.0  # past the start from rest
    assert np.abs(y[late, 0] - np.sin(2 * np.pi * f * (t[late] - analogue))).max() < 0.005
    same, none = firmware_lowpass(t, t[:, None], 0.0)  # 0 Hz: no filter
    assert none == 0.0 and np.array_equal(same, t[:, None])


def test_the_oracle_reads_the_rotor_speeds_as_late_as_the_filtered_accelerometer_leaves_them(raw, tmp_path):
    # the sync stage aligns the motor stream with the accelerometer; with the default recorder the
    # motor readings lead it by the accelerometer filter's delay, which the oracle's rotor_delay
    # (conf/data/sim.yaml) must put back
    import yaml

    root = Path(__file__).resolve().parents[1]
    rotor_delay = yaml.safe_load((root / "params.yaml").read_text())["data"]["rotor_delay"]
    injected = record(raw, tmp_path / "melon_20250601_run1")["motor_lag"]
    assert abs(-injected - rotor_delay) < 0.5e-3


def test_sync_recovers_non_default_lags_and_matches_the_truth(raw, tmp_path):
    path = tmp_path / "melon_20250601_run1"
    injected = record(raw, path, motor_delay=0.037, mocap_latency=0.021, stm_clock=77.7, stm_drift_ppm=-60.0,
                      mocap_clock=999.9, wifi_latency=0.02)
    _, synced, report, flight = process(path)
    assert abs(report["motor_lag"] - injected["motor_lag"]) < 0.010
    assert abs(report["mocap_to_stm_offset"] - injected["mocap_to_stm_offset"]) < 0.010
    truth = pd.read_parquet(tmp_path / "melon_20250601_run1.truth.parquet")
    idx = np.searchsorted(truth["t_stm"].to_numpy(), synced["t"].to_numpy() - 1e-6)
    tr = truth.iloc[idx]
    assert np.allclose(tr["t_stm"].to_numpy(), synced["t"].to_numpy(), atol=1e-6)
    pos = np.sqrt(((flight.y[:, :3] - tr[["p0", "p1", "p2"]].to_numpy()) ** 2).sum(1).mean())
    att = so3.geodesic_angle(torch.from_numpy(tr[["q0", "q1", "q2", "q3"]].to_numpy().copy()),
                             torch.from_numpy(np.ascontiguousarray(flight.y[:, 6:10])))
    rotor = np.sqrt(((flight.u - tr[["omega0", "omega1", "omega2", "omega3"]].to_numpy()) ** 2).mean())
    assert pos < 5e-3 and float(torch.sqrt((att**2).mean())) < 0.01 and rotor < 0.02 * Vehicle().hover_speed
    # the flight segment is where the setpoint is non-zero: the trajectory's 8 s
    assert abs(len(flight) - 801) <= 2


def test_damaged_but_usable_flight_passes_with_warnings(raw, tmp_path):
    path = tmp_path / "melon_20250601_run1"
    record(raw, path, wifi_loss=0.25, mocap_dropouts_per_min=20.0, mocap_dropout_len=(0.2, 0.25))
    _, _, report, flight = process(path)
    assert any("imu" in w and "missing" in w for w in report["warnings"])
    assert any("mocap" in w and "in a row" in w for w in report["warnings"])
    assert np.isfinite(flight.y).all() and np.isfinite(flight.u).all()


# ---- bad input ------------------------------------------------------------------------------




def test_truncated_and_corrupt_bags(bag, tmp_path):
    import shutil

    for kind in ("truncated", "corrupt"):
        dst = tmp_path / kind
        shutil.copytree(bag, dst)
        mcap = next(dst.glob("*.mcap"))
        data = bytearray(mcap.read_bytes())
        if kind == "truncated":
            data = data[: len(data) // 2]
        else:
            data[len(data) // 3 : len(data) // 3 + 4096] = b"\xff" * 4096
        mcap.write_bytes(bytes(data))
        with pytest.raises(DataError, match=rf"{kind}/.*\.mcap: CRC-32 [0-9a-f]{{8}}, but the bag's metadata records"):
            extract_bag(dst, TOPICS)
        # a bag from elsewhere records no CRC: the reader's own checks still catch the damage
        meta = dst / "metadata.yaml"
        meta.write_text(re.sub(r"\n    nanosysid\.crc32\.[^\n]*", "", meta.read_text()).replace("custom_data:\n", "custom_data: null\n"))
        with pytest.raises(DataError, match=rf"{kind}: (cannot read the bag|the bag is damaged or truncated)"):
            extract_bag(dst, TOPICS)


def test_missing_and_empty_topics(bag, tmp_path):
    dst = rewrite(bag, tmp_path / "missing", drop_topics=(IMU,))
    with pytest.raises(DataError, match=rf"missing: topic {IMU} \(imu\) not found; the bag has: "):
        extract_bag(dst, TOPICS)
    dst = rewrite(bag, tmp_path / "empty", lambda topic, m, t: None if topic == IMU else (m, t))
    with pytest.raises(DataError, match=rf"empty: topic {IMU} \(imu\) has no messages"):
        extract_bag(dst, TOPICS)


def clock_jump(topic_name, dt=0.0, dt_recv=0.0, after=300):
    """A change that moves the source stamps (dt, s) and receive times (dt_recv, s) of every
    message of one topic from message ``after`` on."""
    count = {"n": 0}

    def change(topic, m, t):
        if topic == topic_name:
            count["n"] += 1
            if count["n"] > after:
                return shift_stamp(m, dt), t + int(round(dt_recv * 1e9))
        return m, t

    return change


@pytest.mark.parametrize("jump", [5.0, 0.305, 0.3, 0.031])
def test_source_clock_jumping_back_stops_extraction(bag, tmp_path, jump):
    # 0.3 s is a whole number of IMU periods: the stamps after the jump repeat earlier ones
    dst = rewrite(bag, tmp_path / "back", clock_jump(IMU, dt=-jump))
    with pytest.raises(DataError, match=rf"back: topic {IMU} \(imu\), message 300: the source time stamp goes "
                                        r"backwards by (\d+\.\d+) s") as err:
        extract_bag(dst, TOPICS)
    # the size is read from the latency floor of blocks of messages: the jump, give or take the
    # few milliseconds by which that floor varies from block to block
    size = float(re.search(r"backwards by (\d+\.\d+) s", str(err.value)).group(1))
    assert abs(size - jump) < 0.01, size


def test_receive_clock_jumping_back_is_named_as_such(bag, tmp_path):
    dst = rewrite(bag, tmp_path / "recv", clock_jump(IMU, dt_recv=-0.3))
    with pytest.raises(DataError, match=rf"recv: topic {IMU} \(imu\), message \d+: the receive time goes backwards "
                                        r"by 0\.(29|30)\d s against the source time stamps"):
        extract_bag(dst, TOPICS)


def imu_count(bag):
    return len(imu_stamps(bag))


def imu_stamps(bag):
    """The IMU messages' source time stamps (s), in the bag's order."""
    with AnyReader([bag], default_typestore=typestore()) as r:
        return [stamp_of(r.deserialize(raw, c.msgtype)) for c, _, raw in r.messages() if c.topic == IMU]


@pytest.mark.parametrize("where", ["middle", "end"])
def test_single_stamps_out_of_place_are_refused(bag, tmp_path, where):
    """One message stamped 0.305 s early in the middle, or the last three at the end of the
    stream, where no block of later messages shows a jump: each lands, once sorted, on a
    10 ms lattice slot another message holds."""
    stamps = np.array(imu_stamps(bag))
    last = len(stamps)
    if where == "middle":
        # the first message from the 400th whose two slots 0.30 and 0.31 s earlier others hold (a
        # lost packet leaves a slot free)
        moved = {next(n for n in range(400, last) if all(np.min(np.abs(stamps - (stamps[n - 1] - d))) < 0.003
                                                         for d in (0.30, 0.31)))}
    else:
        moved = {last - 2, last - 1, last}
    count = {"n": 0}

    def early(topic, m, t):
        if topic == IMU:
            count["n"] += 1
            if count["n"] in moved:
                return shift_stamp(m, -0.305), t
        return m, t

    first = min(moved) - 1  # the extract counts messages from 0, in receive order
    with pytest.raises(DataError, match=rf"topic {IMU} \(imu\), message {first}: its source time stamp lies "
                                        r"0\.(29|30|31)\d s before those of the messages received around it, among stamps "
                                        r"10 ms apart that leave it no slot"):
        extract_bag(rewrite(bag, tmp_path / where, early), TOPICS)


@pytest.mark.parametrize("scale, words", [
    (0.0, r"every source time stamp is 0\.000 s, over \d+ messages received in \d+\.\d+ s: the source does not "
          "stamp its messages"),
    (1000.0, r"the source time stamps span \d+\.?\d* s while the messages arrived over \d+\.\d+ s \((99\d|1e\+03) times "
             r"as long\): the stamps look like milliseconds read as seconds"),
])
def test_stamps_that_do_not_run_at_the_hosts_pace_are_named(bag, tmp_path, scale, words):
    def stamps(topic, m, t):
        return (shift_stamp(m, stamp_of(m) * (scale - 1.0)), t) if topic == IMU else (m, t)

    with pytest.raises(DataError, match=rf"topic {IMU} \(imu\): " + words):
        extract_bag(rewrite(bag, tmp_path / "stamps", stamps), TOPICS)


def test_late_delivery_and_small_clock_steps_pass(bag, tmp_path):
    """Messages delivered up to 40 ms late (out of order) and a clock step of one period are
    not clock jumps; the table comes out sorted by the source stamp."""
    rng = np.random.default_rng(1)

    def late(topic, m, t):
        return (m, t + int(rng.choice([0, 0, 0, 40e6]))) if topic == IMU else (m, t)

    ref = extract_bag(bag, TOPICS)["imu"]
    got = extract_bag(rewrite(bag, tmp_path / "late", late), TOPICS)["imu"]
    assert np.all(np.diff(got["t_src"]) > 0)
    np.testing.assert_array_equal(got["t_src"], ref["t_src"])
    np.testing.assert_array_equal(got["wx"], ref["wx"])
    tables = extract_bag(rewrite(bag, tmp_path / "step", clock_jump(IMU, dt=0.015)), TOPICS)
    assert len(tables["imu"]) == len(ref)


def test_repeated_stamp(bag, tmp_path):
    seen = {"prev": None, "done": False}

    def repeat(topic, m, t):
        if topic == IMU:
            cur, seen["prev"] = seen["prev"], m
            if cur is not None and not seen["done"]:
                seen["done"] = True
                return dataclasses.replace(m, header=cur.header), t  # the previous message's stamp
        return m, t

    with pytest.raises(DataError, match=rf"repeat: topic {IMU} \(imu\): time stamp .* repeats"):
        extract_bag(rewrite(bag, tmp_path / "repeat", repeat), TOPICS)


def test_topic_of_another_message_type(bag):
    topics = {**TOPICS, "imu": {**TOPICS["imu"], "type": "geometry_msgs/msg/PoseStamped"}}
    with pytest.raises(DataError, match=rf"topic {IMU} \(imu\) carries sensor_msgs/msg/Imu, but the topic map "
                                        "says geometry_msgs/msg/PoseStamped"):
        extract_bag(bag, topics)


@pytest.mark.parametrize("change, message", [
    (("odom", "frame", "world"), r"odom\.frame is not an option of this stream"),
    (("odom", "velocity_frame", "map"), r"odom\.velocity_frame must be one of world, body, got 'map'"),
    (("motors", "pole_pairs", 0), r"motors\.pole_pairs must be a positive number, got 0"),
    (("imu", "type", None), r"imu\.type is missing"),
])
def test_topic_map_errors(bag, change, message):
    from nanosysid.errors import ConfigError

    stream, key, value = change
    spec = dict(TOPICS[stream])
    if value is None:
        del spec[key]
    else:
        spec[key] = value
    with pytest.raises(ConfigError, match=message):
        extract_bag(bag, {**TOPICS, stream: spec})


def test_body_frame_velocity_is_rotated_into_the_world(raw, bag, tmp_path):
    topics = {**TOPICS, "odom": {**TOPICS["odom"], "velocity_frame": "body"}}
    path = tmp_path / "body"
    record_flight(raw, 0, path, topics=topics, cfg=RecorderConfig(), noise=CFG.noise, vehicle=Vehicle())
    with AnyReader([path], default_typestore=typestore()) as r:
        c = next(c for c in r.connections if c.topic == TOPICS["odom"]["topic"])
        m = r.deserialize(next(r.messages(connections=[c]))[2], c.msgtype)
    ref = extract_bag(bag, TOPICS)["odom"]
    # the message holds the body-frame velocity: its length is the world velocity's
    v_body = np.array([m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z])
    assert np.linalg.norm(v_body) == pytest.approx(np.linalg.norm(ref[["vx", "vy", "vz"]].to_numpy()[0]), rel=1e-9)
    got = extract_bag(path, topics)["odom"]
    np.testing.assert_allclose(got[["vx", "vy", "vz"]], ref[["vx", "vy", "vz"]], atol=1e-12)


def test_zero_quaternion_and_motors_never_valid(bag, tmp_path):
    def zero(m):
        q = dataclasses.replace(m.pose.orientation, x=0.0, y=0.0, z=0.0, w=0.0)
        return dataclasses.replace(m, pose=dataclasses.replace(m.pose, orientation=q))

    zero_quat = nth_message(MOCAP, 10, zero)
    with pytest.raises(DataError, match=rf"zero: topic {MOCAP} \(mocap\), message 9: the orientation quaternion "
                                        "has norm 0, not 1"):
        extract_bag(rewrite(bag, tmp_path / "zero", zero_quat), TOPICS)
    motors = TOPICS["motors"]["topic"]

    def invalid(topic, m, t):
        if topic == motors:
            return dataclasses.replace(m, erpm=np.array([1000, TOPICS["motors"]["invalid"], 1000, 1000],
                                                        dtype=m.erpm.dtype)), t
        return m, t

    with pytest.raises(DataError, match=rf"invalid: topic {motors} \(motors\): every reading of m2 is the invalid "
                                        "marker 65535"):
        extract_bag(rewrite(bag, tmp_path / "invalid", invalid), TOPICS)


def test_bag_folder_without_metadata(bag, tmp_path):
    import shutil

    from nanosysid.bags.extract import find_bags

    shutil.copytree(bag, tmp_path / "good")
    shutil.copytree(bag, tmp_path / "bare")
    (tmp_path / "bare" / "metadata.yaml").unlink()
    with pytest.raises(DataError, match=r"bare: a bag without metadata\.yaml"):
        find_bags(tmp_path)
    (tmp_path / "notes").mkdir()  # a folder with no bag files is not a bag
    shutil.rmtree(tmp_path / "bare")
    assert [p.name for p in find_bags(tmp_path)] == ["good"]


def test_nan_value(bag, tmp_path):
    def az_nan(m):
        return dataclasses.replace(m, linear_acceleration=dataclasses.replace(m.linear_acceleration, z=float("nan")))

    nan = nth_message(IMU, 42, az_nan)

    with pytest.raises(DataError, match=rf"nan: topic {IMU} \(imu\), message 41: field az is nan"):
        extract_bag(rewrite(bag, tmp_path / "nan", nan), TOPICS)


def test_streams_that_never_overlap(bag, tmp_path):
    # motion capture stamped and received an hour later than everything else
    dst = rewrite(bag, tmp_path / "apart", lambda topic, m, t: (shift_stamp(m, 3600.0), t + 3600 * 10**9)
                  if topic == MOCAP else (m, t))
    with pytest.raises(DataError, match="apart: the motion capture and the onboard streams never overlap"):
        sync_flight("apart", extract_bag(dst, TOPICS), SyncConfig())


def test_flight_shorter_than_one_window(bag, tmp_path):
    sp = TOPICS["setpoint"]["topic"]
    first = {"t": None}

    def short(topic, m, t):
        if topic == sp and m.pose.position.z != 0:
            first["t"] = first["t"] or t
            if t > first["t"] + 0.3e9:  # the setpoint is non-zero for 0.3 s only
                zero = dataclasses.replace(m.pose.position, x=0.0, y=0.0, z=0.0)
                return dataclasses.replace(m, pose=dataclasses.replace(m.pose, position=zero)), t
        return m, t

    dst = rewrite(bag, tmp_path / "short", short)
    with pytest.raises(DataError, match=r"short: the flight segment has 3\d samples, fewer than the 51 of one window"):
        sync_flight("short", extract_bag(dst, TOPICS), SyncConfig())


def test_stage_error_names_the_bag_and_keeps_old_output(bag, tmp_path):
    import shutil

    bags = tmp_path / "bags"
    shutil.copytree(bag, bags / bag.name)
    out = tmp_path / "extract"
    extract_folder(bags, out, TOPICS)
    before = sorted(p.name for p in (out / bag.name).iterdir())
    rewrite(bag, bags / "broken_20250601_run1", drop_topics=(IMU,))
    with pytest.raises(DataError, match="broken_20250601_run1: topic"):
        extract_folder(bags, out, TOPICS)
    assert sorted(p.name for p in (out / bag.name).iterdir()) == before
    assert not (out / "broken_20250601_run1").exists()


# ---- filtering on analytic signals ----------------------------------------------------------


def test_lowpass_passes_slow_sines_unchanged_and_without_lag():
    t = np.arange(0, 20, 0.01)
    slow = np.sin(2 * np.pi * 1.5 * t + 0.3)
    out = lowpass(slow, 10.0, 100.0)
    inner = slice(200, -200)  # away from the edges' transients
    assert np.abs(out - slow)[inner].max() < 0.01  # same amplitude, same phase: no lag
    fast = np.sin(2 * np.pi * 30 * t)
    assert np.abs(lowpass(fast, 10.0, 100.0))[inner].max() < 0.02  # 30 Hz through 10 Hz: attenuated


def test_quaternion_path_keeps_unit_norm_and_slow_rotations():
    t = np.arange(0, 10, 0.01)
    angle = 0.8 * np.sin(2 * np.pi * 0.7 * t)
    axis = np.array([0.3, -0.4, 0.866])
    axis /= np.linalg.norm(axis)
    q = so3.quat_exp(torch.from_numpy(angle[:, None] * axis)).numpy()
    rng = np.random.default_rng(0)
    noisy = so3.quat_mul(torch.from_numpy(q), so3.quat_exp(torch.from_numpy(rng.normal(scale=0.01, size=(len(t), 3))))).numpy()
    for signal, check in ((q, "unchanged"), (noisy, "denoised")):
        qf = _filtered_quaternions(t, signal)
        assert np.allclose(np.linalg.norm(qf, axis=1), 1, atol=1e-12)
        err = so3.geodesic_angle(torch.from_numpy(q), torch.from_numpy(np.ascontiguousarray(qf))).numpy()[100:-100]
        if check == "unchanged":  # a 0.7 Hz rotation through the 12 Hz filter: no change, no lag
            assert err.max() < 1e-3
        else:
            before = so3.geodesic_angle(torch.from_numpy(q), torch.from_numpy(noisy)).numpy()[100:-100]
            assert np.sqrt((err**2).mean()) < 0.6 * np.sqrt((before**2).mean())


def _filtered_quaternions(t, quats):
    df = pd.DataFrame({"t": t})
    for c in ("x", "y", "z", "vx", "vy", "vz", "wx", "wy", "wz", "ax_body", "ay_body", "az_body",
              "m1_rads", "m2_rads", "m3_rads", "m4_rads"):
        df[c] = 0.0
    df[["qx", "qy", "qz", "qw"]] = quats
    for m in ("mocap", "odom", "imu", "m1", "m2", "m3", "m4"):
        df[f"miss_{m}"] = False
    flight, _ = filter_flight("f", df, FilterConfig())
    return flight.y[:, 6:10]


def test_gap_filling_is_bounded():
    x = np.arange(40, dtype=float) * 2.0
    miss = np.zeros(40, bool)
    miss[5:9] = True  # 4 samples: filled
    miss[20:32] = True  # 12 samples: left
    held = x.copy()
    held[5:9] = -1
    held[20:32] = -1
    out, left = fill_gaps(held, miss, max_gap=10)
    assert np.allclose(out[5:9], x[5:9]) and np.all(out[20:32] == -1)
    assert left == [(20, 12)]


def test_motor_lag_is_one_per_session_and_a_flight_off_it_is_reported(raw, tmp_path):
    # three flights of one session; the third's telemetry lags 20 ms more than the others'
    delays = (0.020, 0.020, 0.040)
    cfg = SyncConfig()
    tables, injected = {}, {}
    for k, delay in enumerate(delays, start=1):
        path = tmp_path / f"melon_20250601_run{k}"
        injected[path.name] = record(raw, path, motor_delay=delay)["motor_lag"]
        tables[path.name] = extract_bag(path, TOPICS)
    evidence = [motor_lag_evidence(n, t["imu"], t["motors"], cfg) for n, t in tables.items()]
    assert all(len(e.proxy) for e in evidence)
    session = motor_lag_estimate(evidence, cfg)
    assert session.method == "sharp thrust transients" and session.units == 3
    odd = "melon_20250601_run3"
    _, report = sync_flight(odd, tables[odd], cfg, motor_lag=session)
    assert report["motor_lag"] == session.value and report["motor_lag_source"] == "session"
    # the odd flight's own estimate finds its own lag, and the report says it is off the session's
    assert abs(report["motor_lag_flight"] - injected[odd]) < 0.005
    assert any("this flight's own lag" in w for w in report["warnings"])
    _, report = sync_flight("melon_20250601_run1", tables["melon_20250601_run1"], cfg, motor_lag=session)
    assert not any("own lag" in w for w in report["warnings"]) or abs(session.value - 0.050) > cfg.lag_tolerance


def _closed_loop_signals(lag: float, seed: int = 0, duration: float = 120.0, step: float = 0.002):
    """A thrust loop by hand, on a 2 ms grid: the reference asks for steps of thrust every second;
    a low-passed disturbance (3 Hz) adds to the measured acceleration, and the loop answers it
    through the rotors 30 ms later; the telemetry records the rotors ``lag`` s late."""
    from scipy.signal import butter, lfilter, sosfiltfilt

    rng = np.random.default_rng(seed)
    n = int(duration / step)
    t = np.arange(n) * step
    ask = np.repeat(rng.normal(size=int(duration) + 1), int(1 / step))[:n]  # thrust steps (m/s^2)
    b, a = butter(1, 1 / (2 * np.pi * 0.03), fs=1 / step)  # rotors: first order, 30 ms
    dist = lfilter(*butter(2, 3.0, fs=1 / step), rng.normal(scale=1.5, size=n))
    late = int(0.03 / step)
    thrust = lfilter(b, a, ask - 0.8 * np.r_[np.zeros(late), dist[:-late]])
    acc = thrust + dist + rng.normal(scale=0.05, size=n)
    recorded = np.interp(t - lag, t, thrust)
    velocity = np.cumsum(acc) * step
    sos = butter(2, (1.0, 20.0), "bandpass", fs=1 / step, output="sos")
    return t, *(sosfiltfilt(sos, x - x.mean()) for x in (ask, acc, recorded, velocity))


def test_the_setpoints_as_instruments_find_a_lag_the_loops_answers_pull_early():
    # The disturbance is in a_z at once and in the rotors 30 ms later (negative): the plain
    # correlation of a_z with the recorded rotors peaks early. The reference's thrust steps do not
    # answer the disturbance, so their moments give the telemetry's 40 ms, and its interval holds it.
    from nanosysid.preprocess.lag import LagEvidence, xcorr_lag

    cfg = SyncConfig()
    t, ask, acc, recorded, velocity = _closed_loop_signals(0.040)
    plain = xcorr_lag(acc, recorded, 0.002, cfg.max_lag, cfg.xcorr_band)
    assert plain < 0.040 - 0.005  # the loop's answers bias the paper's method
    reach = int(round((cfg.lag_reach + cfg.max_lag) / 0.002))
    ask[:reach] = ask[-reach:] = 0.0
    evidence = LagEvidence("hand", 0.002, acc, recorded, 1.0, ask, velocity)
    lag = motor_lag_estimate([evidence], cfg)
    assert lag.method == "the setpoints as instruments" and lag.units >= 50
    assert lag.value == pytest.approx(0.040, abs=0.003)
    assert lag.interval[0] <= 0.040 <= lag.interval[1] and lag.interval[1] - lag.interval[0] < 0.010


def test_a_rotors_wrench_lagging_its_speed_is_in_the_bags_readings_as_in_the_simulators_output(tmp_path):
    # a world whose rotors' wrench follows their speed through a slow lag: the rotors turn at other
    # speeds than those the simulated wrench's squares give, and the bag (what the data chain
    # reads) must record those, as the simulator's direct output does
    raw = simulate_raw([FlightSpec("melon", 1, effects={"thrust_lag": 2.0})], cfg=CFG, progress=False)
    path = tmp_path / "melon_20250601_run1"
    record(raw, path)
    flight = process(path)[3]
    direct = flights_from_record(raw, vehicle=Vehicle(), cfg=CFG, noise=False)[0]
    wrench = np.column_stack([direct.extra[f"true_m{k}_rads"] for k in range(1, 5)])

    def closest(speeds):  # RMS of the bag's readings off ``speeds``, at the best of a few samples' shift
        # (the sync stage's motor-lag estimate is off by a sample or two in such a world)
        return min(float(np.sqrt(((flight.u - speeds[np.clip(np.arange(len(flight)) + k, 0, len(speeds) - 1)])
                                  ** 2).mean())) for k in range(-3, 4))

    # the lag moves the speeds far apart (about 8 % of hover here); the bag holds the turning ones
    assert closest(direct.u) < 0.25 * closest(wrench)
