"""Record simulated flights as ROS 2 bags, with the streams and nuisances of the real rig.

Clocks. ``tau`` is the simulation's true time (0 at the start of the trajectory). The host
(the recording laptop, ROS time) runs at ``host_epoch + tau``. The motion capture stamps its
frames with its own clock, ``mocap_clock + tau``. The STM32 hardware timer, which stamps all
onboard streams, runs at ``stm_clock + (1 + drift) tau``; onboard samples sit on its 100 Hz
tick lattice.

Streams (topics from the topic map):
- mocap pose at 120 Hz, received ``latency`` after capture, with noise and marker dropouts;
- onboard estimate (Odometry) and IMU at 100 Hz over Wi-Fi: received with latency and jitter,
  a few percent of packets lost; the gyro and accelerometer read through the firmware's
  second-order low-pass filters (``gyro_lowpass``, ``accel_lowpass``);
- motor telemetry at 100 Hz, stamped like the IMU but reading the rotor speeds ``motor_delay``
  earlier (plus the ``telemetry_delay`` effect), in units of 100 eRPM, some readings missed;
- status at 10 Hz and the host's position and yaw setpoints at 50 Hz (zero outside the flight).

Beside each bag, ``<flight>.truth.parquet`` holds the true signals on the STM32 tick lattice
and ``<flight>.truth.json`` the clock relations and lags injected, so the processing chain can
be checked against the truth.
"""

from __future__ import annotations

import math
import shutil
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd
import yaml
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from scipy.signal import butter, group_delay, lfilter, lfilter_zi
from scipy.spatial.transform import Rotation, Slerp

from nanosysid.bags.extract import CRC_KEY, rotate
from nanosysid.bags.mcap import set_chunk_crcs
from nanosysid.bags.messages import typestore
from nanosysid.dataio import json_text
from nanosysid.settings import configured
from nanosysid.sim.simulator import (
    NoiseConfig,
    RawRecord,
    accel_bias,
    flight_key,
    interp_columns,
    perturb_attitude,
    velocity_drift,
    vibration_scale,
)
from nanosysid.vehicle import Vehicle

__all__ = ["RecorderConfig", "record_flight", "firmware_lowpass", "ERPM_PER_RADS"]

# mechanical rad/s -> eRPM with 6 pole pairs: eRPM = 6 * rpm = 6 * 60 / (2 pi) * omega
ERPM_PER_RADS = 6 * 60 / (2 * math.pi)


@configured("sim/default.yaml", "recorder")
class RecorderConfig:
    """Rates, clocks and nuisances of the recording rig; their defaults and meaning:
    ``sim.recorder`` of ``conf/sim/default.yaml`` (tau = 0 is the start of the trajectory)."""

    host_epoch: float
    mocap_rate: float
    mocap_clock: float
    mocap_latency: float
    mocap_dropouts_per_min: float
    mocap_dropout_len: tuple[float, float]
    onboard_rate: float
    stm_clock: float
    stm_drift_ppm: float
    wifi_latency: float
    wifi_jitter: float
    wifi_loss: float
    motor_delay: float
    gyro_lowpass: float
    accel_lowpass: float
    motor_missed: float
    odom_pos_noise: float
    status_rate: float
    setpoint_rate: float
    lead: float
    trail: float

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> "RecorderConfig":
        kw = dict(cfg)
        if "mocap_dropout_len" in kw:
            kw["mocap_dropout_len"] = tuple(kw["mocap_dropout_len"])
        return cls(**kw)


@dataclass
class _Stream:
    topic: str
    msgtype: str
    t_recv: np.ndarray  # host receive times (s)
    msgs: list


def _stamp(store, t: float):
    sec = math.floor(t)
    return store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)


def _header(store, t: float, frame: str):
    return store.types["std_msgs/msg/Header"](stamp=_stamp(store, t), frame_id=frame)


def _slerp(t_src: np.ndarray, quats: np.ndarray, t: np.ndarray) -> np.ndarray:
    return Slerp(t_src, Rotation.from_quat(quats))(t).as_quat()


def firmware_lowpass(t: np.ndarray, x: np.ndarray, cutoff: float) -> tuple[np.ndarray, float]:
    """``x (N, C)`` sampled at the even times ``t (N,)`` (s) through a causal second-order
    Butterworth low-pass of ``cutoff`` Hz, started at rest on its first sample (the filter the
    firmware runs on each IMU axis), and the filter's delay (s) at low frequency (its group delay
    at 0 Hz, ``sqrt(2) / (2 pi cutoff)`` for the analogue filter). ``cutoff`` 0 leaves ``x`` as it is."""
    if cutoff <= 0:
        return x, 0.0
    fs = 1.0 / float(t[1] - t[0])
    b, a = butter(2, cutoff, fs=fs)
    y, _ = lfilter(b, a, x, axis=0, zi=lfilter_zi(b, a)[:, None] * x[:1])
    return y, float(group_delay((b, a), w=[1e-6], fs=fs)[1][0]) / fs


def record_flight(
    raw: RawRecord,
    i: int,
    bag_dir: Path,
    *,
    topics: Mapping[str, Mapping[str, Any]],
    cfg: RecorderConfig,
    noise: NoiseConfig,
    vehicle: Vehicle,
) -> dict[str, float]:
    """Write flight ``i`` of a raw record as a ROS 2 bag (mcap, zstd) at ``bag_dir``.

    Returns:
        The injected clock relations and lags (also stored in the truth file).
    """
    store = typestore()
    # the flight's own stream (its seed, trajectory and run), apart from the simulator's
    rng = np.random.default_rng([*flight_key(raw.seeds[i], raw.trajectories[i], raw.runs[i]), 101])
    tau_all, x, omega = raw.t, raw.x[i], raw.omega[i]
    # the recording spans the flight with some lead and trail, within what was simulated
    tau0 = max(-cfg.lead, tau_all[0] + 0.01)
    tau1 = min(raw.durations[i] + cfg.trail, tau_all[-1] - 0.01)
    drift = cfg.stm_drift_ppm * 1e-6

    def host(tau):
        return cfg.host_epoch + tau

    streams: dict[str, _Stream] = {}

    # motion capture: frames at its own rate, captured at tau, stamped with its own clock
    tau_m = np.arange(math.ceil(tau0 * cfg.mocap_rate), math.floor(tau1 * cfg.mocap_rate) + 1) / cfg.mocap_rate
    keep = np.ones(len(tau_m), bool)
    for _ in range(rng.poisson(cfg.mocap_dropouts_per_min * (tau1 - tau0) / 60.0)):
        start = rng.uniform(tau_m[0], tau_m[-1])
        keep &= ~((tau_m >= start) & (tau_m < start + rng.uniform(*cfg.mocap_dropout_len)))
    tau_m = tau_m[keep]
    p_m = interp_columns(tau_all, x[:, 0:3], tau_m) + rng.normal(scale=noise.pos, size=(len(tau_m), 3))
    q_m = perturb_attitude(_slerp(tau_all, x[:, 6:10], tau_m), noise.att, rng)
    Pose, PoseStamped = store.types["geometry_msgs/msg/Pose"], store.types["geometry_msgs/msg/PoseStamped"]
    Point, Quat = store.types["geometry_msgs/msg/Point"], store.types["geometry_msgs/msg/Quaternion"]

    def pose(p, q):
        return Pose(position=Point(x=p[0], y=p[1], z=p[2]), orientation=Quat(x=q[0], y=q[1], z=q[2], w=q[3]))

    streams["mocap"] = _Stream(
        topics["mocap"]["topic"], topics["mocap"]["type"], host(tau_m) + cfg.mocap_latency,
        [PoseStamped(header=_header(store, cfg.mocap_clock + t, "world"), pose=pose(p, q))
         for t, p, q in zip(tau_m, p_m, q_m)],
    )

    # onboard samples on the STM32 tick lattice: tick k at stm time k / rate
    k0 = math.ceil((cfg.stm_clock + (1 + drift) * tau0) * cfg.onboard_rate)
    k1 = math.floor((cfg.stm_clock + (1 + drift) * tau1) * cfg.onboard_rate)
    t_stm = np.arange(k0, k1 + 1) / cfg.onboard_rate
    tau_o = (t_stm - cfg.stm_clock) / (1 + drift)
    n = len(t_stm)
    p_true = interp_columns(tau_all, x[:, 0:3], tau_o)
    v_true = interp_columns(tau_all, x[:, 3:6], tau_o)
    q_true = _slerp(tau_all, x[:, 6:10], tau_o)
    w_true = interp_columns(tau_all, x[:, 10:13], tau_o)
    acc_true = interp_columns(tau_all, raw.wrench[i, :, :3], tau_o) / vehicle.mass
    # what the IMU reads: the truth through the firmware's filters, delayed by them a few ms
    w_read = interp_columns(tau_all, firmware_lowpass(tau_all, x[:, 10:13], cfg.gyro_lowpass)[0], tau_o)
    force_read, accel_delay = firmware_lowpass(tau_all, raw.wrench[i, :, :3], cfg.accel_lowpass)
    acc_read = interp_columns(tau_all, force_read, tau_o) / vehicle.mass
    om_true = interp_columns(tau_all, omega, tau_o)

    def wifi(n_msgs):
        return host(tau_o[:n_msgs]) + cfg.wifi_latency + rng.exponential(cfg.wifi_jitter, size=n_msgs)

    def lost(n_msgs):
        return rng.random(n_msgs) < cfg.wifi_loss

    # onboard estimate: position and attitude near the truth, velocity with its slow error
    v_est = v_true + velocity_drift(n, noise, 1.0 / cfg.onboard_rate, rng) + rng.normal(scale=noise.vel, size=(n, 3))
    p_est = p_true + rng.normal(scale=cfg.odom_pos_noise, size=(n, 3))
    q_est = perturb_attitude(q_true, noise.att, rng)
    if topics["odom"].get("velocity_frame") == "body":  # the ROS convention: twist in child_frame_id
        v_est = rotate(q_est * np.array([-1.0, -1.0, -1.0, 1.0]), v_est)
    T = store.types
    Odometry, Twist, TwistCov, PoseCov, Vec3 = (T["nav_msgs/msg/Odometry"], T["geometry_msgs/msg/Twist"],
                                              T["geometry_msgs/msg/TwistWithCovariance"],
                                              T["geometry_msgs/msg/PoseWithCovariance"], T["geometry_msgs/msg/Vector3"])
    cov36 = np.zeros(36)
    recv, drop = wifi(n), lost(n)
    streams["odom"] = _Stream(
        topics["odom"]["topic"], topics["odom"]["type"], recv[~drop],
        [Odometry(header=_header(store, t_stm[j], "world"), child_frame_id="cf1",
                  pose=PoseCov(pose=pose(p_est[j], q_est[j]), covariance=cov36),
                  twist=TwistCov(twist=Twist(linear=Vec3(x=v_est[j, 0], y=v_est[j, 1], z=v_est[j, 2]),
                                             angular=Vec3(x=0.0, y=0.0, z=0.0)), covariance=cov36))
         for j in np.flatnonzero(~drop)],
    )

    # IMU: gyro and accelerometer, their noise the airframe's vibration; the accelerometer's bias
    # is this power-up's
    # the airframe shakes with the rotors as they turn
    vib = vibration_scale(interp_columns(tau_all, raw.turning(i), tau_o), 1.0 / cfg.onboard_rate,
                          noise.vibration_ref)[:, None]
    gyro = w_read + vib * rng.normal(scale=noise.gyro, size=(n, 3))
    acc = acc_read + vib * rng.normal(scale=noise.accel, size=(n, 3)) + accel_bias(noise, rng)
    Imu, QuatT = T["sensor_msgs/msg/Imu"], T["geometry_msgs/msg/Quaternion"]
    cov9 = np.zeros(9)
    recv, drop = wifi(n), lost(n)
    streams["imu"] = _Stream(
        topics["imu"]["topic"], topics["imu"]["type"], recv[~drop],
        [Imu(header=_header(store, t_stm[j], "cf1"), orientation=QuatT(x=0.0, y=0.0, z=0.0, w=1.0),
             orientation_covariance=cov9,
             angular_velocity=Vec3(x=gyro[j, 0], y=gyro[j, 1], z=gyro[j, 2]), angular_velocity_covariance=cov9,
             linear_acceleration=Vec3(x=acc[j, 0], y=acc[j, 1], z=acc[j, 2]), linear_acceleration_covariance=cov9)
         for j in np.flatnonzero(~drop)],
    )

    # motors: the reading stamped at tick j is the turning rotor's speed motor_lag earlier
    motor_lag = cfg.motor_delay + raw.worlds[i].telemetry_delay
    om_read = interp_columns(tau_all, raw.turning(i), tau_o - motor_lag) + vib * rng.normal(scale=noise.rotor,
                                                                                            size=(n, 4))
    mcfg = topics["motors"]
    counts = np.clip(np.round(om_read * ERPM_PER_RADS / mcfg["erpm_unit"]), 0, mcfg["invalid"] - 1).astype(np.uint16)
    counts[rng.random(counts.shape) < cfg.motor_missed] = mcfg["invalid"]
    Motor = T["nanosysid_msgs/msg/MotorTelemetry"]
    recv, drop = wifi(n), lost(n)
    streams["motors"] = _Stream(
        mcfg["topic"], mcfg["type"], recv[~drop],
        [Motor(header=_header(store, t_stm[j], "cf1"), erpm=counts[j]) for j in np.flatnonzero(~drop)],
    )

    # status, at a tenth of the onboard rate
    every = round(cfg.onboard_rate / cfg.status_rate)
    js = np.arange(0, n, every)
    Status = T["nanosysid_msgs/msg/Status"]
    volts = 4.05 - 0.004 * (tau_o - tau_o[0])  # a slowly draining battery
    streams["status"] = _Stream(
        topics["status"]["topic"], topics["status"]["type"], wifi(n)[js],
        [Status(header=_header(store, t_stm[j], "cf1"), battery_voltage=float(volts[j]), armed=True, flying=True)
         for j in js],
    )

    # setpoints from the host: the reference while the trajectory runs, all zero outside it
    tau_s = np.arange(math.ceil(tau0 * cfg.setpoint_rate), math.floor(tau1 * cfg.setpoint_rate) + 1) / cfg.setpoint_rate
    inside = (tau_s >= 0) & (tau_s <= raw.durations[i])
    p_ref = interp_columns(tau_all, raw.p_ref[i], tau_s) * inside[:, None]
    half_yaw = 0.5 * np.interp(tau_s, tau_all, raw.yaw_ref[i]) * inside
    q_ref = np.column_stack((np.zeros((len(tau_s), 2)), np.sin(half_yaw), np.cos(half_yaw)))  # about z, xyzw
    streams["setpoint"] = _Stream(
        topics["setpoint"]["topic"], topics["setpoint"]["type"], host(tau_s),
        [PoseStamped(header=_header(store, host(t), "world"), pose=pose(p, q)) for t, p, q in zip(tau_s, p_ref, q_ref)],
    )

    _write_bag(bag_dir, streams, store)

    injected = {
        "stm_clock": cfg.stm_clock,
        "stm_drift": drift,
        "mocap_clock": cfg.mocap_clock,
        # stm time minus mocap time of the same instant, at tau = 0
        "mocap_to_stm_offset": cfg.stm_clock - cfg.mocap_clock,
        # the motor readings' lag behind the accelerometer's, what the sync stage estimates: the
        # accelerometer's filter delays it too
        "motor_lag": motor_lag - accel_delay,
    }
    truth = pd.DataFrame({"t_stm": t_stm, "tau": tau_o})
    for name, arr in (("p", p_true), ("v", v_true), ("q", q_true), ("w", w_true), ("acc", acc_true), ("omega", om_true)):
        for c in range(arr.shape[1]):
            truth[f"{name}{c}"] = arr[:, c]
    truth.to_parquet(bag_dir.with_name(bag_dir.name + ".truth.parquet"), index=False)
    bag_dir.with_name(bag_dir.name + ".truth.json").write_text(json_text(injected))
    return injected


def _write_bag(bag_dir: Path, streams: Mapping[str, _Stream], store) -> None:
    """All streams into one bag, messages in order of reception (as a recorder writes them)."""
    if bag_dir.exists():
        shutil.rmtree(bag_dir)
    writer = Writer(bag_dir, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        conns = {k: writer.add_connection(s.topic, s.msgtype, typestore=store) for k, s in streams.items()}
        items = [(int(round(t * 1e9)), k, j) for k, s in streams.items() for j, t in enumerate(s.t_recv)]
        items.sort()
        for t_ns, k, j in items:
            writer.write(conns[k], t_ns, store.serialize_cdr(streams[k].msgs[j], streams[k].msgtype))
    _seal(bag_dir)


def _seal(bag_dir: Path) -> None:
    """Set the chunk CRCs of each storage file and record each file's CRC-32 in the bag's
    metadata (``custom_data``), which the extract stage verifies."""
    meta_path = bag_dir / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text(encoding="utf-8"))
    info = meta["rosbag2_bagfile_information"]
    custom = dict(info.get("custom_data") or {})
    for name in info["relative_file_paths"]:
        set_chunk_crcs(bag_dir / name)
        custom[f"{CRC_KEY}{name}"] = f"{zlib.crc32((bag_dir / name).read_bytes()):08x}"
    info["custom_data"] = custom
    meta_path.write_text(yaml.safe_dump(meta, sort_keys=False), encoding="utf-8")

