"""Recorded flights for the tests: one short simulated Melon flight, its bag, and ways to copy a
bag with some of its messages changed (what a damaged link or a wrong setting would record)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from nanosysid import sim
from nanosysid.bags.messages import typestore
from nanosysid.bags.recorder import RecorderConfig, record_flight
from nanosysid.sim.simulator import SimConfig, simulate_raw
from nanosysid.vehicle import Vehicle

ROOT = Path(__file__).resolve().parents[1]

TOPICS = OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "topics" / "crazyflie.yaml"))
CFG = SimConfig.from_mapping({
    "preroll": 0.5, "postroll": 1.0,
    "trajectories": {"melon": {"duration": 8.0, "circle_time": 6.0, "return_time": 1.5, "ramp_time": 0.15}},
})
IMU, MOCAP, MOTORS = (TOPICS[s]["topic"] for s in ("imu", "mocap", "motors"))


def simulate_melon():
    """The raw record of one 8 s Melon flight."""
    return simulate_raw([sim.FlightSpec("melon", 1)], cfg=CFG, progress=False)


def record(raw, path, topics=None, **recorder):
    """Flight 0 of ``raw`` as a bag at ``path``, with the recorder's settings changed by ``recorder``."""
    return record_flight(raw, 0, path, topics=topics or TOPICS, cfg=RecorderConfig(**recorder), noise=CFG.noise,
                         vehicle=Vehicle())


def rewrite(src, dst, change=lambda topic, msg, t: (msg, t), drop_topics=()):
    """Copy a bag message by message, through ``change(topic, msg, t) -> (msg, t) | None``."""
    store = typestore()
    with AnyReader([src], default_typestore=store) as r:
        writer = Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP)
        with writer:
            conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store)
                     for c in r.connections if c.topic not in drop_topics}
            for c, t, raw in r.messages():
                if c.id not in conns:
                    continue
                out = change(c.topic, r.deserialize(raw, c.msgtype), t)
                if out is not None:
                    writer.write(conns[c.id], out[1], store.serialize_cdr(out[0], c.msgtype))
    return dst


def stamp_of(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def shift_stamp(msg, dt):
    total = stamp_of(msg) + dt
    st = msg.header.stamp
    new = dataclasses.replace(st, sec=int(np.floor(total)), nanosec=int(round((total - np.floor(total)) * 1e9)) % 10**9)
    return dataclasses.replace(msg, header=dataclasses.replace(msg.header, stamp=new))


def nth_message(topic_name, n, edit):
    """A change that applies ``edit(msg) -> msg`` to the n-th message (from 1) of one topic."""
    count = {"n": 0}

    def change(topic, m, t):
        if topic == topic_name:
            count["n"] += 1
            if count["n"] == n:
                return edit(m), t
        return m, t

    return change
