"""The Python API with impossible values: one clear error naming the value, never a score. The
pipeline's settings are checked on every command line; these are the same bounds where the
library is called directly (a vehicle of mass -1 kg, a model stepping every 0.02 s on 100 Hz
data, k_F in rpm units, a hand-edited ``params.json``, two flights of one name)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from nanosysid import identify, predictors, protocol
from nanosysid.errors import ConfigError, DataError, PredictionError
from nanosysid.synthetic import synthetic_flights
from nanosysid.vehicle import Vehicle

CLASS = "unchecked setting"

VEHICLES = [
    ({"mass": -1.0}, "vehicle.mass must be a positive number, got -1.0"),
    ({"mass": 0.0}, "vehicle.mass must be a positive number, got 0.0"),
    ({"inertia": (1.7e-5, -1.7e-5, 2.9e-5)}, "vehicle.inertia must be a positive number, got (1.7e-05, -1.7e-05"),
    ({"inertia": (1.7e-5, 2.9e-5)}, "vehicle.inertia must be three numbers (body axes x, y, z), got (1.7e-05, 2.9e-05)"),
    ({"k_f": math.nan}, "vehicle.k_f must be a positive number, got nan"),
    ({"k_m": -2e-10}, "vehicle.k_m must be a positive number, got -2e-10"),
    ({"arm": math.inf}, "vehicle.arm must be a positive number, got inf"),
    ({"gravity": 0.0}, "vehicle.gravity must be a positive number, got 0.0"),
    ({"mass": "0.04"}, "vehicle.mass must be a positive number, got '0.04'"),
]


@pytest.mark.parametrize("change,words", VEHICLES, ids=[w.split(" must")[0] + str(list(c.values())[0])
                                                        for c, w in VEHICLES])
def test_an_impossible_vehicle_is_refused_wherever_it_is_made(change, words):
    with pytest.raises(ConfigError, match="^Vehicle: ") as e:
        Vehicle(**change)
    assert words in str(e.value)
    # and through a model's options, as a config mapping
    with pytest.raises(ConfigError, match="Vehicle: "):
        predictors.predictor("physics", vehicle={k: list(v) if isinstance(v, tuple) else v for k, v in change.items()})


STEPS = [
    (dict(dt=-0.01), "dt = -0.01 s; the flights are sampled every 0.01 s, and a model steps once per sample"),
    (dict(dt=0.02), "dt = 0.02 s"),
    (dict(dt=0.0), "dt = 0.0 s"),
    (dict(dt=math.nan), "dt = nan s"),
    (dict(substeps=0), "substeps = 0, expected a positive whole number"),
    (dict(substeps=1.5), "substeps = 1.5"),
]


@pytest.mark.parametrize("kind", ["physics", "physics_full"])
@pytest.mark.parametrize("change,words", STEPS, ids=[w.split(",")[0] for _, w in STEPS])
def test_a_physics_model_steps_once_per_sample(kind, change, words):
    with pytest.raises(ConfigError, match=f"{kind}: ") as e:
        predictors.predictor(kind, **change)
    assert words in str(e.value)


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """A params.json as the identify stage writes it, of the nominal vehicle."""
    v = Vehicle()
    path = tmp_path_factory.mktemp("identified") / "params.json"
    path.write_text(json.dumps({"format": identify.FORMAT, "k_f": v.k_f, "k_m": v.k_m}))
    return path


EDITED = [
    ({"k_f": 1e10}, "field 'k_f' is 10000000000.0: k_f = 1e+10, more than 1.25 times off"),
    ({"k_f": 3.708e-08 / 92}, "field 'k_f' is"),  # rpm for rad/s
    ({"k_m": 1e-6}, "field 'k_m' is 1e-06: k_m / k_f"),
    ({"k_m": 1e-14}, "field 'k_m' is 1e-14"),
]


@pytest.mark.parametrize("change,words", EDITED, ids=[w.split(":")[0] + str(list(c.values())[0]) for c, w in EDITED])
def test_a_hand_edited_identification_is_refused_not_scored(tmp_path, identified, change, words):
    d = json.loads(identified.read_text())
    d.update(change)
    path = tmp_path / "params.json"
    path.write_text(json.dumps(d))
    with pytest.raises(DataError, match=str(path)) as e:
        predictors.predictor("physics", identified=str(path))
    assert words in str(e.value) and "rerun it" in str(e.value)
    # the file as written is read
    assert predictors.predictor("physics", identified=str(identified)) is not None


def test_rotor_speeds_in_rpm_are_refused_by_identify():
    flights = synthetic_flights([f"chirp_x_run{k}" for k in (1, 2)], 400, seed=4)
    rpm = [dataclasses.replace(f, u=f.u * 60 / (2 * np.pi)) for f in flights]
    # the right unit gives the vehicle's k_F (the synthetic flights are of the nominal vehicle)
    thrust, _ = identify.identify(flights, Vehicle())
    assert thrust.coef == pytest.approx(Vehicle().k_f, rel=0.05)
    with pytest.raises(DataError, match=r"identify: k_F = .* times the vehicle's nominal .* rotor speeds' unit"):
        identify.identify(rpm, Vehicle())


def test_two_flights_of_one_name_are_refused_not_one_dropped():
    a, b = synthetic_flights(["melon_x_run1", "melon_x_run2"], 80, seed=1)
    b = dataclasses.replace(b, name=a.name)
    with pytest.raises(DataError, match="flight name.*melon_x_run1 given more than once"):
        protocol.evaluate(predictors.predictor("naive"), [a, b], horizon=5)


# the API given what a stage never passes: each refusal names the function and the argument
@pytest.fixture(scope="module")
def api_flights():
    return synthetic_flights(["chirp_x_run1", "chirp_x_run2", "melon_x_run1"], 200, seed=3)


def _calls(fl):
    naive = predictors.predictor("naive")
    melon = fl[2]
    return [
        ("evaluate given one Flight", lambda: protocol.evaluate(naive, melon, horizon=10),
         DataError, r"evaluate: flights must be a list of flights, got one Flight \(melon_x_run1\)"),
        ("evaluate given a dict", lambda: protocol.evaluate(naive, {"a": melon}, horizon=10),
         DataError, r"evaluate: flights must be a list of flights, got a dict"),
        ("evaluate given names", lambda: protocol.evaluate(naive, ["melon_x_run1"], horizon=10),
         DataError, r"evaluate: flights\[0\] is a str, not a Flight"),
        ("evaluate given an array as predictor", lambda: protocol.evaluate(np.zeros(3), [melon], horizon=10),
         ConfigError, r"evaluate: predict must be a predictor"),
        ("a predictor of words", lambda: protocol.evaluate(lambda y0, u: np.full((len(y0), 10, 13), "a"), [melon],
                                                           horizon=10),
         protocol.PredictionError, r"flight melon_x_run1: the predictor: values that are not numbers"),
        ("windows of a horizon of 10.5", lambda: protocol.windows(melon, 10.5),
         ConfigError, r"horizon must be a whole number >= 1, got 10.5"),
        ("predictions from a negative start", lambda: protocol.predictions(naive, melon, horizon=10, starts=[-1]),
         ConfigError, r"predictions: starts must be whole numbers from 0 to 189"),
        ("predictions from a start past the end", lambda: protocol.predictions(naive, melon, horizon=10, starts=[5000]),
         ConfigError, r"starts must be whole numbers from 0 to 189 .* got \[5000\]"),
        ("score of words", lambda: protocol.score(np.full((2, 3, 13), "x"), np.zeros((2, 3, 13))),
         protocol.PredictionError, r"score: y_true: values that are not numbers"),
        ("a Flight of lists of words", lambda: protocol.Flight("a_b_run1", ["x"] * 3, np.zeros((3, 4)), np.zeros((3, 13))),
         DataError, r"flight a_b_run1: t must be an array of numbers"),
        ("identify given one Flight", lambda: identify.identify(melon, Vehicle()),
         DataError, r"identify: flights must be a list of flights, got one Flight"),
        ("identify without the accelerometer", lambda: identify.identify(
            [dataclasses.replace(fl[0], extra={})], Vehicle()), DataError, r"flight chirp_x_run1 has no column 'az_body'"),
        ("identify with a window below the order", lambda: identify.identify(fl[:2], Vehicle(), window=2),
         ConfigError, r"window = 2 \(identify.savgol_window\) with polyorder = 3"),
        ("identify with a window beyond the flights", lambda: identify.identify(fl[:2], Vehicle(), window=5000),
         ConfigError, r"at most the shortest flight's 200 samples"),
        ("identify on flights whose rotors never change", lambda: identify.identify(
            [dataclasses.replace(f, u=np.zeros_like(f.u)) for f in fl[:2]], Vehicle()),
         DataError, r"identify: "),
    ]


@pytest.mark.parametrize("index", range(15))
def test_the_apis_functions_name_the_argument_they_cannot_take(api_flights, index):
    case, call, error, words = _calls(api_flights)[index]
    with pytest.raises(error, match=words):
        call()


def test_evaluate_reads_flights_given_as_a_generator_once_and_scores_them_all(api_flights):
    naive = predictors.predictor("naive")
    listed = protocol.evaluate(naive, api_flights, horizon=10)
    generated = protocol.evaluate(naive, (f for f in api_flights), horizon=10)
    assert generated.n_windows == listed.n_windows == 3 * 190
    assert all(np.array_equal(generated.mae[k], listed.mae[k]) for k in listed.mae)


DISCOVER = [
    ("one Flight for the training flights", lambda fl: dict(train_flights=fl[0], test_flights=[fl[2]]),
     DataError, r"discover.run: train_flights must be a list of flights, got one Flight"),
    ("no test flight", lambda fl: dict(train_flights=fl[:2], test_flights=[]),
     DataError, r"discover.run: test_flights is empty"),
    ("a negative delay", lambda fl: dict(train_flights=fl[:2], test_flights=[fl[2]], delays=[-0.01]),
     ConfigError, r"discover.run: delays must be finite numbers of seconds >= 0 .* got -0.01"),
    ("a delay of nan", lambda fl: dict(train_flights=fl[:2], test_flights=[fl[2]], delays=[math.nan]),
     ConfigError, r"delays must be finite numbers .* got nan"),
]


@pytest.mark.parametrize("case, args, error, words", DISCOVER, ids=[c for c, *_ in DISCOVER])
def test_discover_run_names_the_argument_it_cannot_take(api_flights, case, args, error, words):
    from nanosysid import discover

    with pytest.raises(error, match=words):
        discover.run(analysis=False, **args(api_flights))


SIM = [
    ("a negative strength", dict(effects={"rotor_drag": -5.0}), r"effects: 'rotor_drag' = -5.0; a world effect's "
                                                                 r"strength is a finite number >= 0"),
    ("a strength of nan", dict(effects={"rotor_drag": math.nan}), r"'rotor_drag' = nan"),
    ("an infinite strength", dict(effects={"rotor_drag": math.inf}), r"'rotor_drag' = inf"),
    ("an unknown effect", dict(effects={"wind": 1.0}), r"effects: unknown effect 'wind'; the world's effects are"),
    ("a negative run", dict(run=-3), r"FlightSpec: run must be a whole number >= 1, got -3"),
    ("a negative seed", dict(seed=-1), r"FlightSpec: seed must be a whole number >= 0, got -1"),
    ("a wrench of the wrong shape", dict(effects={}, extra_wrench=lambda *a: np.zeros(7)),
     r"extra_wrench: called as fn\(t \(1,\), x \(1, 13\), .* did not give \(force, torque\)"),
    ("a wrench of nan", dict(effects={}, extra_wrench=lambda t, x, o, od: (torch_full(x, math.nan), torch_full(x, 0.0))),
     r"extra_wrench: its force on a hovering state is \[\[nan, nan, nan\]\]"),
    ("an extra wrench that is no function", dict(effects={}, extra_wrench=3.0), r"extra_wrench must be a function"),
]


def torch_full(x, value):
    import torch

    return torch.full_like(x[..., :3], value)


@pytest.mark.parametrize("case, args, words", SIM, ids=[c for c, *_ in SIM])
def test_the_simulators_api_names_the_argument_before_flying(case, args, words):
    from nanosysid import sim

    with pytest.raises(ConfigError, match=words):
        sim.simulate_flight("chirp", **args)


def test_a_negative_run_count_and_an_oracle_of_a_negative_strength_are_refused():
    from nanosysid import sim

    with pytest.raises(ConfigError, match=r"runs: 'chirp' = -1; the number of runs of a trajectory is a whole number"):
        sim.simulate_flights({"chirp": -1})
    with pytest.raises(ConfigError, match=r"effects: 'rotor_drag' = -2.0"):
        predictors.predictor("oracle", effects={"rotor_drag": -2.0})


@pytest.mark.parametrize("effects, words", [
    ({"turbulence": 50.0}, r"below the floor .* the effects \{'turbulence': 50.0\} are beyond what it flies"),
    ({"rotor_drag": 1e6}, r"the simulation diverged .* in effects \{'rotor_drag': 1000000.0\}"),
])
def test_a_world_beyond_the_controller_is_refused_by_the_api_naming_its_effects(effects, words):
    from nanosysid import campaign, sim

    cfg = dataclasses.replace(campaign.short_flights_config(3.0), compile=False)
    with pytest.raises(ConfigError, match=words):
        sim.simulate_flight("chirp", effects=effects, cfg=cfg)


def test_discover_run_refuses_a_training_flight_given_as_its_test_flight():
    from nanosysid import discover

    fl = synthetic_flights(["chirp_x_run1", "chirp_x_run2"], 1500, seed=3)
    with pytest.raises(DataError, match=r"chirp_x_run1: 1500 of its 1500 distinct samples are the same samples as in "
                                        r"chirp_x_run1"):
        discover.run(fl, [fl[0]], analysis=False)


@pytest.mark.parametrize("scale, words", [(1e6, r"is 1\.\d+e\+09 rad/s at sample 0"), (-1.0, r"is -\d+\.?\d* rad/s")])
def test_rotor_speeds_no_motor_turns_at_are_not_scored(api_flights, scale, words):
    f = dataclasses.replace(api_flights[2], u=api_flights[2].u * scale)
    with pytest.raises(DataError, match=r"flight melon_x_run1: column 'm1_rads' " + words):
        protocol.evaluate(predictors.predictor("physics"), [f], horizon=10)


def test_the_campaigns_api_and_the_oracle_refuse_a_strength_no_world_has():
    from nanosysid import campaign

    with pytest.raises(ConfigError, match=r"effects: 'rotor_drag' = -3.0; a world effect's strength is a finite"):
        campaign.simulate([campaign.HiddenWorld(0, {"rotor_drag": -3.0})], campaign.Setup())
    with pytest.raises(ConfigError, match=r"effects: 'rotor_drag' = nan"):
        predictors.predictor("oracle", effects={"rotor_drag": math.nan})


def test_an_oracle_whose_world_leaves_the_numbers_names_the_world(api_flights):
    with pytest.raises(PredictionError, match=r"the oracle's world \(body_drag 2, rotor_drag 1e\+09\) predicts values "
                                              r"that are not numbers from window \d+, step \d+"):
        protocol.evaluate(predictors.predictor("oracle", effects={"rotor_drag": 1e9, "body_drag": 2.0}, compile=False),
                          [api_flights[2]], horizon=10)


def test_a_campaign_world_whose_flights_cannot_be_identified_is_named(api_flights, monkeypatch):
    """Turbulence 50 times the default's wrecks the flights; the identified k_M comes out
    negative, and the refusal names the world that did it, not only the vehicle."""
    from nanosysid import campaign
    from nanosysid.vehicle import Vehicle

    def wrecked(world, flights, setup=None):
        Vehicle(k_m=-1.39e-10)  # what the identification of the wrecked flights gives

    monkeypatch.setattr(campaign, "_identified", wrecked)
    with pytest.raises(ConfigError, match=r"^world 0 \(turbulence 50\): its flights cannot be identified: .*k_m must be "
                                          r"a positive number, got -1\.39e-10"):
        campaign.judge(campaign.HiddenWorld(0, {"turbulence": 50.0}), api_flights)
