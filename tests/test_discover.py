"""Discovery on simulated flights where the hidden effect and its strength are known.

The world's effects (nature, :mod:`nanosysid.sim.world`) and the library's (knowledge,
:mod:`nanosysid.effects`) have their own names; ``NAMED_BY`` says which library entry
describes which world effect, and ``TRUTH`` gives the world's strength-1.0 magnitudes in
the library entry's parametrisation, written out by hand from the world's description.

Flights are shorter than the benchmark's (20 s) and one run per trajectory: the effects are
still clearly visible, and every world simulates in seconds. Train: square, random, chirp;
test: melon; measurement noise on.
"""

import math

import numpy as np
import pytest

import re

from nanosysid import discover, sim
from nanosysid.sim import SimConfig

CFG = SimConfig.from_mapping({"trajectories": {
    "random": {"box": [2.4, 2.4, 1.2], "duration": 20.0, "n_points": 18},
    "melon": {"ramp_time": 0.15, "duration": 20.0, "circle_time": 15.0, "return_time": 3.0},
    "chirp": {"duration": 20.0},
}})

NAMED_BY = {
    "rotor_drag": "induced_drag",
    "body_drag": "quadratic_drag",
    "telemetry_delay": "input_delay",
    "com_offset": "cg_offset",
    "motor_asymmetry": "rotor_spread",
    "rotor_inertia": "rotor_gyro",
}
# world effects no library entry describes: nature has more than knowledge
BEYOND_LIBRARY = {"inertia_offset", "turbulence", "unsteady_thrust"}
TRUTH = {
    "rotor_drag": (1.8e-6, 1.0e-6),  # K_xy, K_z [kg/rad]
    "body_drag": (1.5e-3, 3.0e-3),  # c_xy, c_z [kg/m]
    "telemetry_delay": (0.030,),  # s
    "com_offset": (1.5e-3, -1.0e-3),  # r_x, r_y [m]
    "motor_asymmetry": (0.030, -0.020, 0.025, -0.035),
    "rotor_inertia": (3.9e-8,),  # kg m^2
}

_cache = {}


def discovered(effects):
    key = tuple(sorted(effects))
    if key not in _cache:
        strengths = {name: 1.0 for name in effects}
        flights = sim.simulate_flights({"square": 1, "random": 1, "chirp": 1, "melon": 1}, effects=strengths, seed=1,
                                       cfg=CFG, progress=False)
        train = [f for f in flights if f.trajectory != "melon"]
        test = [f for f in flights if f.trajectory == "melon"]
        _cache[key] = discover.run(train, test, oracle=sim.oracle(strengths))
    return _cache[key]


def test_every_world_effect_has_a_library_entry_of_another_name():
    assert set(NAMED_BY) | BEYOND_LIBRARY == set(sim.EFFECTS) and not set(NAMED_BY) & BEYOND_LIBRARY
    assert set(NAMED_BY.values()) <= set(discover.LIBRARY)
    assert not set(sim.EFFECTS) & set(discover.LIBRARY)


@pytest.mark.parametrize("effect", [e for e in TRUTH if e != "rotor_drag"])
def test_a_hidden_effect_is_named_fitted_and_closes_the_gap(effect):
    r = discovered([effect])
    assert r.found and r.found[0].name == NAMED_BY[effect], [f.name for f in r.found]
    first = r.found[0]
    got = np.array(list(first.params.values()))
    truth = np.array(TRUTH[effect])
    assert np.all(np.abs(got - truth) <= 0.2 * np.abs(truth)), (first.params, truth)
    # the gap between nominal and oracle, in the quantities the effect acts on, where the
    # effect makes one (an effect on force barely moves position over 0.5 s, say)
    checked = 0
    for q in first.touches:
        gap = r.before.simerr[q] - r.oracle.simerr[q]
        if gap > 0.05 * r.before.simerr[q]:
            closed = (r.before.simerr[q] - r.after.simerr[q]) / gap
            assert closed >= 0.5, (q, r.before.simerr[q], r.after.simerr[q], r.oracle.simerr[q])
            checked += 1
    assert checked >= 1


def test_per_rotor_drag_is_named_by_its_force_and_its_moments_stay_unexplained():
    # the world drags each rotor at its hub with that rotor's own air velocity v + omega x r_i;
    # the library's induced_drag acts at the centre of mass with the body's: it fits the force
    # (the sum over the four rotors) but not the moments of hub forces about the centre of mass,
    # which dominate the rotation error of this world
    r = discovered(["rotor_drag"])
    first = r.found[0]
    assert first.name == "induced_drag"
    got, truth = np.array(list(first.params.values())), np.array(TRUTH["rotor_drag"])
    assert np.all(np.abs(got - truth) <= 0.2 * np.abs(truth)), (first.params, truth)
    assert r.before.simerr["R"] > 5 * r.oracle.simerr["R"]
    assert r.after.simerr["R"] > 0.5 * r.before.simerr["R"]


def test_nothing_hidden_nothing_named():
    r = discovered([])
    assert r.found == []
    assert r.name == "physics"


def test_two_hidden_effects_are_both_named():
    r = discovered(["rotor_drag", "com_offset"])
    assert {f.name for f in r.found} == {"induced_drag", "cg_offset"}
    world = {v: k for k, v in NAMED_BY.items()}
    for f in r.found:
        got, truth = np.array(list(f.params.values())), np.array(TRUTH[world[f.name]])
        assert np.all(np.abs(got - truth) <= 0.2 * np.abs(truth)), f.name


def test_model_round_trips_through_its_file_and_reports(tmp_path):
    from nanosysid import benchmark
    from nanosysid.discover.model import load_discovered, save_discovered
    from nanosysid.report.discovery import gap_closed, write_report

    r = discovered(["com_offset"])
    effects = {"cg_offset": {"coefficients": r.model.step.theta.tolist()}}
    save_discovered(tmp_path / "model.json", r.vehicle, effects, r.model.delay)
    back = load_discovered(tmp_path / "model.json")
    flight = sim.simulate_flight("melon", 1, effects={"com_offset": 1.0}, seed=3, cfg=CFG)
    a = benchmark.evaluate(r.model, [flight], horizon=20)
    b = benchmark.evaluate(back, [flight], horizon=20)
    assert a.simerr == b.simerr
    write_report(r, tmp_path / "report")
    text = (tmp_path / "report" / "report.md").read_text()
    assert "`cg_offset` named" in text
    # the report's coefficients are the truth (1.5 mm forward, 1.0 mm right) within 20 %
    for param, truth in (("r_x", 1.5e-3), ("r_y", -1.0e-3)):
        value = float(re.search(rf"{param} \[m\] = ([-+0-9.e]+)", text).group(1))
        assert abs(value - truth) <= 0.2 * abs(truth), (param, value)
    closed = [v for v in gap_closed(r).values() if v is not None]
    assert closed and all(math.isfinite(v) and v > 0.5 for v in closed)
    for fig in ("mae_horizon", "channels", "effects"):
        assert (tmp_path / "report" / "figures" / f"{fig}.png").read_bytes()[:4] == b"\x89PNG"
