"""The scoring API checks the truth it scores against, not only the predictions: a bad flight
is one error naming the flight, the column and the sample, never a NaN score, a perfect score
for a zero quaternion, or 50 Hz data scored as 100 Hz."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nanosysid import protocol
from nanosysid.errors import DataError
from nanosysid.synthetic import synthetic_flights

CLASS = "silent acceptance"


def hold(y0, u):
    """The naive predictor: the state held."""
    return np.repeat(np.asarray(y0)[:, None], np.asarray(u).shape[1], axis=1)


@pytest.fixture(scope="module")
def flight():
    return synthetic_flights(["melon_20250101_run1"], 80, seed=1)[0]


def spoil(flight, what, value, sample=17):
    arr = getattr(flight, what).copy()
    arr[sample, value[0]] = value[1]
    return dataclasses.replace(flight, **{what: arr})


def zero_quaternion(flight, sample=17):
    y = flight.y.copy()
    y[sample, 6:10] = 0.0
    return dataclasses.replace(flight, y=y)


def scaled_quaternion(flight, factor, sample=17):
    y = flight.y.copy()
    y[sample, 6:10] *= factor
    return dataclasses.replace(flight, y=y)


def resampled(flight, step):
    return dataclasses.replace(flight, t=flight.t[::step].copy(), u=flight.u[::step].copy(),
                               y=flight.y[::step].copy(), extra={})


def shifted_time(flight, by, sample=40):
    """The time stamps from ``sample`` on moved by ``by`` s: a gap, a repeat or a step back."""
    t = flight.t.copy()
    t[sample:] += by
    return dataclasses.replace(flight, t=t)


BAD = [
    ("NaN position", lambda f: spoil(f, "y", (0, np.nan)), ["'x'", "sample 17", "finite"]),
    ("inf velocity", lambda f: spoil(f, "y", (4, np.inf)), ["'vy'", "sample 17"]),
    ("NaN body rate", lambda f: spoil(f, "y", (12, np.nan)), ["'wz'", "sample 17"]),
    ("NaN rotor speed", lambda f: spoil(f, "u", (2, np.nan)), ["sample 17", "finite"]),
    ("-inf rotor speed", lambda f: spoil(f, "u", (0, -np.inf)), ["sample 17"]),
    ("zero quaternion", zero_quaternion, ["quaternion", "sample 17", "norm 0"]),
    ("half-norm quaternion", lambda f: scaled_quaternion(f, 0.5), ["quaternion", "norm 0.5"]),
    ("quaternion 5 % long", lambda f: scaled_quaternion(f, 1.05), ["quaternion", "norm 1.05"]),
    ("50 Hz flight", lambda f: resampled(f, 2), ["50 Hz", "'t'"]),
    ("25 Hz flight", lambda f: resampled(f, 4), ["25 Hz"]),
    ("a 0.5 s gap inside", lambda f: shifted_time(f, 0.5), ["between samples 39 and 40", "step of 0.51 s"]),
    ("the clock stepping back", lambda f: shifted_time(f, -0.2), ["between samples 39 and 40", "step of -0.19 s"]),
    ("a repeated time stamp", lambda f: shifted_time(f, -0.01), ["between samples 39 and 40", "step of 0 s"]),
]

ENTRY_POINTS = {
    "evaluate": lambda f: protocol.evaluate(hold, [f], horizon=5),
    "predictions": lambda f: protocol.predictions(hold, f, horizon=5),
    "template_frame": lambda f: protocol.template_frame(hold, f, horizon=5),
}


@pytest.mark.parametrize("entry", list(ENTRY_POINTS))
@pytest.mark.parametrize("case,make,words", BAD, ids=[b[0] for b in BAD])
def test_a_bad_truth_is_blamed_on_the_flight_not_the_predictor(flight, entry, case, make, words):
    with pytest.raises(DataError) as e:
        ENTRY_POINTS[entry](make(flight))
    msg = str(e.value)
    assert f"flight {flight.name}" in msg, msg
    for w in words:
        assert w in msg, (w, msg)


def test_a_good_flight_still_scores_and_a_sound_jitter_is_accepted(flight):
    t = flight.t + np.random.default_rng(0).normal(0, 2e-5, len(flight.t))  # clock jitter of 20 µs
    jittered = dataclasses.replace(flight, t=np.sort(t))
    a = protocol.evaluate(hold, [flight], horizon=5)
    b = protocol.evaluate(hold, [jittered], horizon=5)
    assert np.isfinite(a.simerr["p"]) and a.simerr == b.simerr


@pytest.mark.parametrize("case", ["nan", "zero quaternion", "long quaternion"])
def test_score_checks_its_truth(case):
    y = np.zeros((3, 4, 13))
    y[..., 9] = 1.0
    pred = y.copy()
    if case == "nan":
        y[1, 2, 0] = np.nan
    elif case == "zero quaternion":
        y[1, 2, 6:10] = 0.0  # would read as a rotation error of 0 rad
    else:
        y[1, 2, 6:10] *= 1.5
    with pytest.raises(DataError, match=r"score: the tru(e|th).*window 1, step 3"):
        protocol.score(y, pred)
