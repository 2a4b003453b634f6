"""Discovery on simulated flights where the hidden effect and its strength are known.

Flights are shorter than the benchmark's (20 s) and one run per trajectory: the effects are
still clearly visible, and every world simulates in seconds. Train: square, random, chirp;
test: melon; measurement noise on.
"""

import math

import numpy as np
import pytest

from nanosysid import discover, sim
from nanosysid.sim import SimConfig
from nanosysid.sim import effects as E

CFG = SimConfig.from_mapping({"trajectories": {
    "random": {"box": [2.4, 2.4, 1.2], "duration": 20.0, "n_points": 18},
    "melon": {"ramp_time": 0.15, "duration": 20.0, "circle_time": 15.0, "return_time": 3.0},
    "chirp": {"duration": 20.0},
}})

# the simulator's strength-1.0 truth in each candidate's parametrisation
TRUTH = {
    "rotor_drag": (E.ROTOR_DRAG[0], E.ROTOR_DRAG[2]),
    "body_drag": (E.BODY_DRAG[0], E.BODY_DRAG[2]),
    "telemetry_delay": (E.TELEMETRY_DELAY,),
    "com_offset": (E.COM_OFFSET[0], E.COM_OFFSET[1]),
    "motor_asymmetry": E.MOTOR_ASYMMETRY,
    "rotor_inertia": (E.ROTOR_INERTIA,),
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


def test_candidate_library_has_the_simulator_catalogue():
    assert set(sim.EFFECTS) <= set(discover.CANDIDATES)
    for name, c in discover.CANDIDATES.items():
        assert c.params and set(c.touches) <= {"p", "v", "R", "w"}, name


@pytest.mark.parametrize("effect", list(TRUTH))
def test_a_hidden_effect_is_named_fitted_and_closes_the_gap(effect):
    r = discovered([effect])
    assert r.found and r.found[0].name == effect, [f.name for f in r.found]
    first = r.found[0]
    got = np.array(list(first.params.values()))
    truth = np.array(TRUTH[effect])
    assert np.all(np.abs(got - truth) <= 0.2 * np.abs(truth)), (first.params, truth)
    assert first.evidence["heldout_gain"] >= r.threshold and first.evidence["folds_improved"] >= 2
    assert set(first.evidence["stderr"]) == set(first.params)
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


def test_nothing_hidden_nothing_named():
    r = discovered([])
    assert r.found == []
    assert r.name == "physics"
    assert all(row["heldout_gain"] < r.threshold for row in r.rounds[0])
    # the augmented model is the nominal one with its k_F and k_M refitted: the same scores
    for q in ("p", "v", "R", "w"):
        assert r.after.simerr[q] == pytest.approx(r.before.simerr[q], rel=0.02)


def test_two_hidden_effects_are_both_named():
    r = discovered(["rotor_drag", "com_offset"])
    assert {f.name for f in r.found} == {"rotor_drag", "com_offset"}
    for f in r.found:
        got, truth = np.array(list(f.params.values())), np.array(TRUTH[f.name])
        assert np.all(np.abs(got - truth) <= 0.2 * np.abs(truth)), f.name
    # every round's chosen effect was the best candidate of its round
    for f in r.found:
        assert r.rounds[f.evidence["round"] - 1][0]["candidate"] == f.name


def test_model_round_trips_through_its_file_and_reports(tmp_path):
    from nanosysid import benchmark
    from nanosysid.discover.model import load_model, save_model
    from nanosysid.discover.report import gap_closed, write_report

    r = discovered(["com_offset"])
    effects = {"com_offset": {"coefficients": r.model.step.theta.tolist()}}
    save_model(tmp_path / "model.json", r.vehicle, effects, r.model.delay)
    back = load_model(tmp_path / "model.json")
    flight = sim.simulate_flight("melon", 1, effects={"com_offset": 1.0}, seed=3, cfg=CFG)
    a = benchmark.evaluate(r.model, [flight], horizon=20)
    b = benchmark.evaluate(back, [flight], horizon=20)
    assert a.simerr == b.simerr
    write_report(r, tmp_path / "report")
    text = (tmp_path / "report" / "report.md").read_text()
    assert "`com_offset` named" in text and "r_x [m] = 0.0015" in text
    assert all(math.isfinite(v) and v > 0.5 for v in gap_closed(r).values() if v is not None)
    for fig in ("mae_horizon", "channels", "effects"):
        assert (tmp_path / "report" / "figures" / f"{fig}.png").read_bytes()[:4] == b"\x89PNG"
