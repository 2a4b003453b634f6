"""The initialization-window track: its windows, the history a predictor gets, the rate map's fit
against a rotation law integrated by hand, and the held-out fit by reference trajectory."""

import math

import numpy as np
import pytest

from nanosysid import window
from nanosysid.dataio import Flight
from nanosysid.errors import ConfigError, DataError
from nanosysid.report.window import beats_paper, paper_best

DT = 0.01
J = np.array([2.4e-5, 2.5e-5, 3.2e-5])
# body torque per rotor speed squared: a made-up full-rank map (N m s²/rad²)
TORQUE_MAP = np.array([[1.0, -1.0, -1.0, 1.0], [-1.0, -1.0, 1.0, 1.0], [0.3, -0.3, 0.3, -0.3]]) * 1e-9


def _flight(name: str, T: int = 400, *, seed: int = 0, bias=(0.0, 0.0, 0.0)) -> Flight:
    """A flight whose body rates follow dω/dt = torque_map Ω² / J + bias (Euler, one step a
    sample), Ω a random walk about hover; level attitude, no translation."""
    rng = np.random.default_rng(seed)
    u = 1800.0 + np.cumsum(rng.normal(0.0, 15.0, (T, 4)), axis=0)
    u -= u.mean(axis=1, keepdims=True) - 1800.0  # keeps the collective near hover, the torques balanced
    acc = (u * u) @ TORQUE_MAP.T / J + np.asarray(bias)
    w = np.zeros((T, 3))
    for t in range(1, T):
        w[t] = w[t - 1] + DT * acc[t - 1]
    y = np.zeros((T, 13))
    y[:, 9] = 1.0
    y[:, 10:13] = w
    return Flight(name=name, t=np.arange(T) * DT, u=u, y=y)


def test_windows_hold_the_samples_before_each_start():
    f = _flight("square_20250601_run1", T=120)
    w = window.windows(f, horizon=20, init=30)
    assert len(w["start"]) == 120 - 20 - 30
    i = 7
    s = w["start"][i]
    assert s == 30 + i
    np.testing.assert_array_equal(w["y0"][i], f.y[s])
    np.testing.assert_array_equal(w["y_hist"][i], f.y[s - 30:s])
    np.testing.assert_array_equal(w["u_hist"][i], f.u[s - 30:s])
    np.testing.assert_array_equal(w["u"][i], f.u[s:s + 20])
    np.testing.assert_array_equal(w["y"][i], f.y[s + 1:s + 21])
    with pytest.raises(DataError, match="fewer than init"):
        window.windows(f, horizon=80, init=40)
    with pytest.raises(ConfigError, match="init"):
        window.windows(f, horizon=20, init=0)


def test_only_a_predictor_that_asks_gets_the_history():
    f = _flight("square_20250601_run1", T=150)
    seen = {}

    def plain(y0, u, **extra):
        seen["plain"] = set(extra)
        return np.repeat(y0[:, None], u.shape[1], axis=1)

    def last_sample(y0, u, *, y_hist, u_hist):
        # the newest sample of the window is the one just before the start
        np.testing.assert_array_equal(y_hist.shape[1:], (50, 13))
        np.testing.assert_array_equal(u_hist.shape[1:], (50, 4))
        seen["history"] = True
        return np.repeat(y0[:, None], u.shape[1], axis=1)

    last_sample.history = True
    a = window.evaluate(plain, [f], horizon=20, init=50)
    b = window.evaluate(last_sample, [f], horizon=20, init=50)
    assert seen == {"plain": set(), "history": True}
    assert a.n_windows == b.n_windows == 150 - 20 - 50
    np.testing.assert_allclose(a.simerr["w"], b.simerr["w"])


def test_orientation_of_a_constant_rate_is_the_rotation_by_rate_times_time():
    rate = np.array([0.0, 0.0, 2.0])  # rad/s about z
    q = window.orientation(np.array([[0.0, 0.0, 0.0, 1.0]]), rate[None], np.tile(rate, (1, 10, 1)))
    angle = 2.0 * DT * np.arange(1, 11)
    np.testing.assert_allclose(q[0, :, 2], np.sin(angle / 2), atol=1e-12)
    np.testing.assert_allclose(q[0, :, 3], np.cos(angle / 2), atol=1e-12)


def _hold(y0, u):
    return np.repeat(np.asarray(y0)[:, None], u.shape[1], axis=1)


def test_rate_map_learns_the_torque_law_it_is_given():
    """Rates made by integrating the torque law: the map fitted on two flights predicts a third
    one's rates but for the ridge's small bias, where holding the rate is off by the integrated torque."""
    train = [_flight("square_20250601_run1", seed=1), _flight("random_20250601_run1", seed=2)]
    test = [_flight("melon_20250601_run1", seed=3)]
    fit = window.fit_rate_map(train, base=_hold, torque_map=TORQUE_MAP, inertia=J, horizon=20, init=20)
    mapped = window.evaluate(fit, test, horizon=20, init=20)
    held = window.evaluate(_hold, test, horizon=20, init=20)
    assert held.simerr["w"] > 0.1
    assert mapped.simerr["w"] < 1e-4 * held.simerr["w"]  # the ridge's bias, 1e-6 relative
    # one step ahead the rate changes by the torque equation's own change alone: coefficient 1
    np.testing.assert_allclose(fit.coef[0][:, 0], 1.0, atol=1e-3)  # the ridge shares a little with the lagged torque
    np.testing.assert_allclose(fit.coef[0][:, 1:], 0.0, atol=1e-3)


def test_held_out_by_reference_sees_what_one_reference_alone_carries():
    """Each reference flies with its own constant torque: the map fitted on every flight learns
    each reference's (in sample, it helps), refitted without a reference it cannot know that one's
    (held out, it does not); the law itself carries over between references either way."""
    names = ["square_20250601_run1", "square_20250601_run2", "random_20250601_run1", "random_20250601_run2",
             "chirp_20250601_run1", "chirp_20250601_run2"]
    biases = {"square": (300.0, 0.0, 0.0), "random": (-300.0, 0.0, 0.0), "chirp": (0.0, 300.0, 0.0)}
    flights = [_flight(n, seed=i, bias=biases[n.split("_")[0]]) for i, n in enumerate(names)]
    fit = window.fit_rate_map(flights, base=_hold, torque_map=TORQUE_MAP, inertia=J, horizon=20, init=20)
    in_sample = window.evaluate(fit, flights, horizon=20, init=20)
    held_out = window.held_out_rate_map(fit, flights, horizon=20, init=20)
    assert held_out.n_windows == in_sample.n_windows
    assert held_out.simerr["w"] > 1.2 * in_sample.simerr["w"]
    with pytest.raises(DataError, match="not the ones"):
        window.held_out_rate_map(fit, flights[:4], horizon=20, init=20)


def test_paper_best_rows_are_the_papers_table():
    best = paper_best()
    # the paper's table of numerical performance, its SimErr column (hand-copied from the paper)
    assert best["p"] == ("physics", 2.3223)
    assert best["v"] == ("phys_res", 10.4033)
    assert best["R"] == ("physics", 5.1013)
    assert best["w"] == ("phys_res", 28.9873)
    assert beats_paper({"p": 2.0, "v": 9.5, "R": 5.0, "w": 28.99}) == {"p": True, "v": True, "R": True, "w": False}
    assert math.isclose(best["w"][1], 28.9873)
