"""The physical consistency check passes every flight it must: every simulated flight of the
default world and every real flight of the paper's campaign (each log as the rig extract reads it,
from the team's data folder where it is beside the checkout); and its figures are those of hand-made
motions, whose slopes are known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from nanosysid.consistency import K_F_FACTOR, SLOPE_BAND, Expect, check, check_flight
from nanosysid.errors import DataError

ROOT = Path(__file__).resolve().parents[1]
RIG = yaml.safe_load((ROOT / "conf" / "rig" / "crazyflie-2025-10-17.yaml").read_text())
VEHICLE = yaml.safe_load((ROOT / "conf" / "vehicle" / "cf21bl.yaml").read_text())
EXPECT = Expect(VEHICLE["mass"], VEHICLE["k_f"], VEHICLE["gravity"])


def _within(found: dict) -> None:
    slopes = [s for k in ("rates", "velocity", "position") for s in found.get(k, [])]
    assert slopes and all(SLOPE_BAND[0] <= s <= SLOPE_BAND[1] for s in slopes), found
    assert 1 / K_F_FACTOR < found["k_f_ratio"] < K_F_FACTOR, found


def test_every_simulated_flight_of_the_default_world_passes():
    from nanosysid import sim

    runs = yaml.safe_load((ROOT / "conf" / "sim" / "default.yaml").read_text())["runs"]
    flights = sim.simulate_flights(runs, progress=False)  # the default world (effects=None)
    assert len(flights) >= 15
    for f in flights:
        found = check_flight(f, EXPECT)
        # every flight's attitude and rotors are judged; a hover with yaw sweeps barely translates
        assert found["rates"] and 1 / K_F_FACTOR < found["k_f_ratio"] < K_F_FACTOR, (f.name, found)
        if not f.name.startswith("yawsweep"):
            _within(found)


def _local() -> Path | None:
    folder = (ROOT / RIG["local"]).resolve() / "raw"
    return folder if folder.is_dir() and any(folder.glob("*.parquet")) else None


@pytest.mark.skipif(_local() is None, reason="the team's data folder (rig.local) is not beside the checkout")
def test_every_real_flight_of_the_campaign_passes_as_the_rig_extract_reads_it():
    from nanosysid.rig.logs import LogSpec, log_streams, read_log

    spec = LogSpec.from_mapping(RIG["logs"])
    judged = 0
    for stem in spec.flights:
        (path,) = _local().rglob(f"{stem}.parquet")
        df, _ = read_log(path, spec.aliases)
        _, rules = log_streams(df, spec, str(path), EXPECT)
        if rules["segment"]["complete"]:
            _within(rules["consistency"])
            judged += 1
    assert judged >= 15


def _motion(n: int = 2000, dt: float = 0.01):
    """A hand-made flight: sinusoidal position and yaw, its exact velocity, rates and specific force."""
    t = np.arange(n) * dt
    w1, w2 = 2 * np.pi * 0.5, 2 * np.pi * 0.3
    p = np.stack([0.5 * np.sin(w1 * t), 0.4 * np.cos(w2 * t), 1 + 0.2 * np.sin(w2 * t)], 1)
    v = np.stack([0.5 * w1 * np.cos(w1 * t), -0.4 * w2 * np.sin(w2 * t), 0.2 * w2 * np.cos(w2 * t)], 1)
    acc = np.stack([-0.5 * w1 ** 2 * np.sin(w1 * t), -0.4 * w2 ** 2 * np.cos(w2 * t), -0.2 * w2 ** 2 * np.sin(w2 * t)], 1)
    yaw = 0.8 * np.sin(w1 * t)
    rot = Rotation.from_euler("z", yaw[:, None])
    rates = np.stack([np.zeros(n), np.zeros(n), 0.8 * w1 * np.cos(w1 * t)], 1)  # about z, body = world
    g = EXPECT.gravity
    a_body = rot.inv().apply(acc + [0, 0, g])
    # rotor speeds whose thrust, at the vehicle's k_F, is the mass times the specific force
    omega = np.sqrt(EXPECT.mass * np.linalg.norm(a_body, axis=1) / (4 * EXPECT.k_f))
    y = np.concatenate([p, v, rot.as_quat(), rates], 1)
    return t, np.repeat(omega[:, None], 4, 1), y, a_body


def test_a_hand_made_motion_gives_slopes_of_one_and_the_vehicles_k_f():
    t, u, y, a = _motion()
    found = check(t, u, y, a, EXPECT, "hand")
    _within(found)
    assert all(abs(s - 1) < 0.02 for k in ("rates", "velocity", "position") for s in found[k]), found
    # mean thrust k_F mean ΣΩ² = m mean |a|: the ratio is 1 by construction
    assert found["k_f_ratio"] == pytest.approx(1.0, rel=1e-9)


@pytest.mark.parametrize("column, factor, words", [
    (slice(0, 3), 1000.0, "in mm rather than m"),
    (slice(3, 6), 10.0, "ten times too large"),
    (slice(10, 13), 180 / np.pi, "in deg/s rather than rad/s"),
])
def test_a_hand_made_motion_with_one_column_group_scaled_is_refused_by_its_factor(column, factor, words):
    t, u, y, a = _motion()
    y = y.copy()
    y[:, column] *= factor
    with pytest.raises(DataError, match=words):
        check(t, u, y, a, EXPECT, "hand")
