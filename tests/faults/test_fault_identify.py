"""identify refuses coefficients no propeller has, or that the flights do not determine, with the
numbers, instead of writing them for every model downstream."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nanosysid import identify, synthetic
from nanosysid.errors import DataError
from nanosysid.vehicle import Vehicle

CLASS = "wrong result written"

NAMES = [f"chirp_20250101_run{k}" for k in (1, 2, 3)]


@pytest.fixture(scope="module")
def flights():
    return synthetic.synthetic_flights(NAMES, 600, noise=0.01, seed=4)


def fits(flights):
    """The paper's two fits, unchecked (the identify stage checks them with the calibration's k_M)."""
    return identify.fit_thrust(flights, Vehicle()), identify.fit_yaw_moment(flights, Vehicle())


def scaled_speeds(factor):
    return lambda fl: [dataclasses.replace(f, u=f.u * factor) for f in fl]


def accelerometer(change):
    return lambda fl: [dataclasses.replace(f, extra={**f.extra, "az_body": change(f.extra["az_body"])}) for f in fl]


def hover(fl):
    """Every rotor at the same speed: no yaw torque to regress on."""
    out = []
    for f in fl:
        u = np.repeat(f.u.mean(axis=1, keepdims=True), 4, axis=1) * (1 + 1e-4 * np.random.default_rng(1).standard_normal(f.u.shape))
        out.append(dataclasses.replace(f, u=u))
    return out


CASES = [
    ("rotor speeds scaled by 1e-7 (k_F 1e6 times)", scaled_speeds(1e-7), "k_F", "outside 1/1.25 to 1.25"),
    ("rotor speeds in rpm", scaled_speeds(60 / (2 * np.pi)), "k_F", "check the rotor speeds' unit"),
    ("rotor speeds in krpm", scaled_speeds(60 / (2 * np.pi) / 1000), "k_F", "outside 1/1.25 to 1.25"),
    ("accelerometer without gravity", accelerometer(lambda az: az - 9.81), "k_F", "with gravity"),
    ("accelerometer in g", accelerometer(lambda az: az / 9.81), "k_F", "outside 1/1.25 to 1.25"),
    # eRPM to rad/s: omega = eRPM / pole pairs * 2 pi / 60, so 7 pole pairs read for 6 scale the speeds by 6/7
    ("7 motor pole pairs for 6", scaled_speeds(6 / 7), "k_F", "motors.pole_pairs and erpm_unit"),
    ("5 motor pole pairs for 6", scaled_speeds(6 / 5), "k_F", "motors.pole_pairs and erpm_unit"),
    ("eRPM read as units of 10 for 100", scaled_speeds(0.1), "k_F", "motors.pole_pairs and erpm_unit"),
    ("accelerometer drowned in noise", accelerometer(lambda az: az + 40 * np.random.default_rng(2).standard_normal(az.shape)),
     "k_F", "explains less than 0.5"),
    ("hover only: no yaw excitation", hover, "k_M", "do not determine"),
]


@pytest.mark.parametrize("case,spoil,coefficient,words", CASES, ids=[c[0] for c in CASES])
def test_an_implausible_or_undetermined_coefficient_is_refused_with_its_numbers(flights, case, spoil, coefficient, words):
    thrust, yaw = fits(spoil(flights))
    with pytest.raises(DataError, match=rf"identify: {coefficient} = ") as e:
        identify.check_plausible(thrust, yaw, Vehicle())
    assert words in str(e.value) and "R²" in str(e.value), str(e.value)
    if coefficient == "k_F":  # the Python API's identify refuses the thrust fit alike
        with pytest.raises(DataError, match=r"identify: k_F = ") as e:
            identify.identify(spoil(flights), Vehicle())
        assert words in str(e.value)


def test_the_flights_the_coefficients_were_made_with_pass(flights):
    identify.check_plausible(*fits(flights), Vehicle())
