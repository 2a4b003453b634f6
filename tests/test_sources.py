"""Telling a function of the input history from one of time, on signals made by hand: two runs of
one reference share what the reference makes and nothing of their own disturbances."""

import numpy as np

from nanosysid.dataio import Flight
from nanosysid.discover.sources import reference_check, reference_pairs, source


def _flights(rng, n=2000):
    t = np.arange(n) * 0.01
    path = np.column_stack([np.sin(0.5 * t), np.cos(0.3 * t), 1 + 0.2 * np.sin(t)])
    other = np.column_stack([np.sin(0.9 * t + 1), np.cos(0.2 * t), 1 + 0.3 * np.cos(t)])
    out = []
    for name, p in (("square_20250101_run1", path), ("square_20250101_run2", path),
                    ("random_20250101_run1", other), ("square_20250101_run3", other)):
        y = np.zeros((n, 13))
        y[:, 0:3] = p + rng.normal(0, 0.02, (n, 3))
        y[:, 9] = 1.0
        out.append(Flight(name=name, t=t.copy(), u=np.full((n, 4), 2000.0), y=y, extra={}))
    return out


def _slow(rng, n, scale=1.0):
    """A slow random signal: white noise through a 1 s moving average."""
    return scale * np.convolve(rng.normal(size=n + 99), np.ones(100) / 10, mode="valid")


def test_runs_of_one_reference_are_paired_by_their_positions_not_their_names():
    rng = np.random.default_rng(0)
    flights = _flights(rng)
    pairs = reference_pairs(flights, [f.t for f in flights])
    # run 3 of the square flew another path: no partner; the random flight has no other run
    assert pairs.partners == [1, 0, -1, -1]
    n = len(flights[0])
    assert np.array_equal(pairs.index[:n], np.arange(n) + n) and np.all(pairs.index[2 * n:] == -1)


def _paired(seed):
    """Four flights (two runs of one reference among them), their pairs, samples a flight, blocks."""
    rng = np.random.default_rng(seed)
    flights = _flights(rng)
    n = len(flights[0])
    return rng, flights, reference_pairs(flights, [f.t for f in flights]), n, np.arange(4 * n) // 200


def test_a_residual_that_repeats_with_the_reference_is_of_the_reference_one_that_does_not_is_of_time():
    rng, flights, pairs, n, blocks = _paired(1)
    common = _slow(rng, n, 3.0)
    noise = rng.normal(size=4 * n)  # the noise floor: residuals are in its units
    repeating = noise + np.concatenate([common, common, _slow(rng, n, 3.0), _slow(rng, n, 3.0)])
    of_time = noise + np.concatenate([_slow(rng, n, 3.0) for _ in range(4)])
    assert source(repeating, pairs, blocks, 0.01)["source"] == "the reference"
    got = source(of_time, pairs, blocks, 0.01)
    assert got["source"] == "time" and abs(got["repeat_share"]) < 0.3
    lone = reference_pairs(flights[2:], [f.t for f in flights[2:]])
    assert source(of_time[2 * n:], lone, blocks[:2 * n], 0.01)["source"] == "undecided"


def test_a_fit_to_the_controllers_answer_to_a_disturbance_has_an_instrumental_slope_near_zero():
    # closed loop: the rotor-speed column is the reference's demand plus the controller's answer to
    # the run's own disturbance d; least squares of d on the column finds a slope, the partner
    # run's column (same demand, another disturbance) finds none
    rng, flights, pairs, n, blocks = _paired(2)
    folds = np.arange(blocks.max() + 1) % 10
    demand = _slow(rng, n, 2.0)
    d = np.concatenate([_slow(rng, n, 2.0) for _ in range(4)])
    column = np.concatenate([demand, demand, _slow(rng, n, 2.0), _slow(rng, n, 2.0)]) + d
    contribution = np.zeros((4 * n, 6))
    contribution[:, 3] = column
    disturbance = np.zeros((4 * n, 6))
    disturbance[:, 3] = d + rng.normal(size=4 * n)
    ols = float((column * disturbance[:, 3]).sum() / (column ** 2).sum())
    got = reference_check(contribution, disturbance, pairs, blocks, folds)
    assert ols > 0.3 and got["ci"][0] < 0 < got["ci"][1] and not got["holds"]
    # a real lag: the residual is the column itself (plus noise): slope 1
    lag = np.zeros((4 * n, 6))
    lag[:, 3] = column + rng.normal(size=4 * n)
    got = reference_check(contribution, lag, pairs, blocks, folds)
    assert got["holds"] and got["ci"][0] < 1 < got["ci"][1]


def test_a_fit_that_least_squares_attenuated_fails_the_check_though_it_repeats():
    # what repeats with the reference is twice what the entry's least-squares fit says (its
    # columns also carry the controller's answer, anti-correlated with a biased correction beside
    # it): the instrumental slope is 2, the two estimates disagree, the entry is not named
    rng, flights, pairs, n, blocks = _paired(3)
    folds = np.arange(blocks.max() + 1) % 10
    demand = _slow(rng, n, 2.0)
    reference = np.concatenate([demand, demand, _slow(rng, n, 2.0), _slow(rng, n, 2.0)])
    column = reference + np.concatenate([_slow(rng, n, 2.0) for _ in range(4)])
    contribution = np.zeros((4 * n, 6))
    contribution[:, 3] = column
    residual = np.zeros((4 * n, 6))
    residual[:, 3] = 2.0 * reference + rng.normal(size=4 * n)
    got = reference_check(contribution, residual, pairs, blocks, folds)
    assert got["ci"][0] < 2.0 < got["ci"][1] and not got["holds"]


def test_a_constant_two_runs_flown_back_to_back_share_repeats_only_until_each_flights_mean_is_removed():
    # runs 1 and 2 of the square share a constant of 3 noise floors (the vehicle as it was) over a
    # disturbance of time of their own (std about 1): power above the noise about 9 + 1, of which
    # the constant's 9 repeats (about 90 %); with each flight's own mean removed, nothing does
    rng, flights, pairs, n, blocks = _paired(2)
    noise = rng.normal(size=4 * n)
    disturbance = np.concatenate([_slow(rng, n, 1.0) for _ in range(4)])
    disturbance -= np.repeat([disturbance[k * n:(k + 1) * n].mean() for k in range(4)], n)  # zero mean per flight
    left = noise + disturbance + np.repeat([3.0, 3.0, -1.0, 2.0], n)
    got = source(left, pairs, blocks, 0.01, flight=np.repeat(np.arange(4), n))
    power = np.mean(disturbance[:2 * n] ** 2) + 9.0
    assert abs(got["repeat_share"] - 9.0 / power) < 0.05, got
    assert abs(got["within_share"]) < 0.05, got
    assert "within_share" not in source(left, pairs, blocks, 0.01)
