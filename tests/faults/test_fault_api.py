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
from nanosysid.errors import ConfigError, DataError
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
