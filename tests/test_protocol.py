"""Evaluation protocol: windows, metric known answers, the API, the built-in models."""

import re

import numpy as np
import pytest
import torch

from nanosysid import predictors, protocol, so3, synthetic
from nanosysid.dataio import Flight
from nanosysid.errors import ConfigError, DataError, PredictionError


def still_flight(name, T):
    y = np.zeros((T, 13))
    y[:, 9] = 1.0
    return Flight(name=name, t=np.arange(T) * 0.01, u=np.zeros((T, 4)), y=y)


@pytest.mark.parametrize("T, H", [(51, 50), (120, 50), (300, 7)])
def test_window_count_and_alignment(T, H):
    f = still_flight("melon_x_run1", T)
    f.y[:, 0] = np.arange(T)  # x = sample index
    f.u[:, 0] = np.arange(T)
    y0, u, y = protocol.windows(f, H)
    assert len(y0) == T - H
    assert u.shape == (T - H, H, 4) and y.shape == (T - H, H, 13)
    t = 5 if T - H > 5 else 0
    assert y0[t, 0] == t
    assert np.array_equal(u[t, :, 0], np.arange(t, t + H))  # u_t .. u_{t+H-1}
    assert np.array_equal(y[t, :, 0], np.arange(t + 1, t + H + 1))  # y_{t+1} .. y_{t+H}


def test_rotated_prediction_gives_exactly_that_angle():
    rng = np.random.default_rng(0)
    N, H = 40, 5
    q = so3.quat_exp(torch.from_numpy(rng.normal(size=(N, H, 3))))
    y_true = np.zeros((N, H, 13))
    y_true[..., 6:10] = q.numpy()
    angle = 0.123
    axis = rng.normal(size=(N, H, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    y_pred = y_true.copy()
    y_pred[..., 6:10] = so3.quat_mul(q, so3.quat_exp(torch.from_numpy(axis * angle))).numpy()
    y_pred[..., 6:10] *= -1  # the other sign of the same rotation
    s = protocol.score(y_true, y_pred)
    assert np.allclose(s.mae["R"], angle, atol=1e-12)
    assert np.all(s.mae["p"] == 0) and np.all(s.mae["w"] == 0)


def test_constructed_errors_give_expected_mae():
    N, H = 4, 3
    y_true = np.zeros((N, H, 13))
    y_true[..., 9] = 1
    y_pred = y_true.copy()
    # window i is off by (3, 4, 0) * i in position: error 5 i, mean over windows 5 * 1.5
    y_pred[..., 0] = 3 * np.arange(N)[:, None]
    y_pred[..., 1] = 4 * np.arange(N)[:, None]
    # velocity error grows with the horizon: 0.1 h
    y_pred[..., 5] = 0.1 * np.arange(1, H + 1)
    s = protocol.score(y_true, y_pred)
    assert np.allclose(s.mae["p"], 7.5)
    assert np.allclose(s.mae["v"], [0.1, 0.2, 0.3])
    assert np.isclose(s.simerr["v"], 0.6) and np.isclose(s.simerr["p"], 22.5)


def test_evaluate_averages_flights_and_keeps_each():
    flights = [still_flight("melon_a_run1", 80), still_flight("melon_a_run2", 130)]

    def offset_predict(y0, u):
        out = np.repeat(y0[:, None], u.shape[1], axis=1)
        out[..., 2] += 1.0 if len(y0) == 30 else 3.0  # flight 1 has 30 windows, flight 2 has 80
        return out

    s = protocol.evaluate(offset_predict, flights, horizon=50)
    assert s.n_windows == 30 + 80
    assert np.allclose(s.per_flight["melon_a_run1"].mae["p"], 1.0)
    assert np.allclose(s.per_flight["melon_a_run2"].mae["p"], 3.0)
    assert np.allclose(s.mae["p"], 2.0)  # mean over flights, not pooled over windows
    assert np.isclose(s.simerr["p"], 100.0)


def test_evaluate_batches_give_the_same_answer_and_torch_output_is_accepted():
    flights = synthetic.synthetic_flights(["melon_s_run1"], 300, seed=3)
    phys = predictors.predictor("physics")
    a = protocol.evaluate(phys, flights, horizon=20, batch_size=7)
    b = protocol.evaluate(phys, flights, horizon=20, batch_size=10_000)
    for k in a.mae:
        assert np.allclose(a.mae[k], b.mae[k], rtol=1e-12)
    c = protocol.evaluate(lambda y0, u: torch.from_numpy(phys(y0, u)), flights, horizon=20)
    assert np.allclose(c.mae["v"], a.mae["v"])


def test_the_rollouts_kept_while_scoring_are_those_of_the_flight_at_their_starts(tmp_path):
    # a predictor whose every prediction tells its start and step: y_hat[i, h, 0] = start + (h + 1) / 100
    flight = still_flight("melon_a_run1", 97)
    flight.y[:, 0] = np.arange(97)

    def tell(y0, u):
        out = np.repeat(y0[:, None], u.shape[1], axis=1)
        out[..., 0] = y0[:, None, 0] + np.arange(1, u.shape[1] + 1) / 100
        return out

    # 7 windows a batch, so that kept starts fall inside batches and on their edges
    scores, kept = protocol.evaluate(tell, [flight], horizon=10, batch_size=7, keep=6)
    k = kept["melon_a_run1"]
    assert np.allclose(k.last[:, 0], np.arange(87) + 0.10)  # start i, step 10
    assert list(k.starts) == list(range(0, 87, 6))
    assert np.allclose(k.paths[:, :, 0], np.arange(0, 87, 6)[:, None] + np.arange(1, 11)[None] / 100)
    assert scores.n_windows == 87
    protocol.save_kept(kept, tmp_path)
    back = protocol.load_kept(tmp_path, [flight], horizon=10, stride=6)["melon_a_run1"]
    assert np.array_equal(back.paths, k.paths) and np.array_equal(back.last, k.last)
    with pytest.raises(DataError, match=r"kept every 6 starts, not every 5; rerun the evaluate stage"):
        protocol.load_kept(tmp_path, [flight], horizon=10, stride=5)
    with pytest.raises(DataError, match=r"no rollouts of flight melon_a_run1 at horizon 20"):
        protocol.load_kept(tmp_path, [flight], horizon=20)


def test_a_rollout_runs_on_one_thread_whatever_the_callers_count():
    # a loop over time on small tensors: with two threads each step waits on the other, and on
    # any busy neighbour process (the slowdown beside two busy processes was 10x)
    seen = []

    def record(y0, u):
        seen.append(torch.get_num_threads())
        return np.repeat(y0[:, None], u.shape[1], axis=1)

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        protocol.evaluate(record, [still_flight("melon_a_run1", 60)], horizon=5, batch_size=20)
        protocol.predictions(record, still_flight("melon_a_run1", 60), horizon=5)
        after = torch.get_num_threads()
    finally:
        torch.set_num_threads(before)
    assert seen == [1, 1, 1, 1] and after == 2


def test_predictor_with_wrong_shape_is_rejected():
    with pytest.raises(PredictionError, match=r"predictor returned shape \(55, 13\) on flight melon_a_run1"):
        protocol.evaluate(lambda y0, u: y0, [still_flight("melon_a_run1", 60)], horizon=5)


def test_builtin_models_on_flights_of_the_nominal_dynamics():
    flights = synthetic.synthetic_flights(["melon_s_run1", "melon_s_run2"], 400, substeps=1, seed=1)
    naive = protocol.evaluate(predictors.predictor("naive"), flights)
    phys = protocol.evaluate(predictors.predictor("physics"), flights)
    full = protocol.evaluate(predictors.predictor("physics_full"), flights)
    # same integrator and parameters as the data: exact up to rounding
    assert all(v < 1e-9 for v in full.simerr.values())
    # dw/dt = 0 is exact at h = 1 only in the kinematic part, and far better than naive
    for k in ("p", "v"):
        assert phys.simerr[k] < 0.1 * naive.simerr[k]
    assert np.allclose(phys.mae["w"], naive.mae["w"])  # both hold w constant


def test_model_by_unknown_name():
    with pytest.raises(ConfigError, match="unknown model kind 'nope'"):
        predictors.predictor("nope")


def test_scores_round_trip_through_dict():
    flights = synthetic.synthetic_flights(["melon_s_run1"], 120, seed=2)
    s = protocol.evaluate(predictors.predictor("physics"), flights, horizon=10)
    back = protocol.Scores.from_dict(s.to_dict())
    assert back.simerr == s.simerr and list(back.per_flight) == ["melon_s_run1"]


def naive_with(change):
    """The naive predictor with ``change(pred)`` applied to its output."""
    def predict(y0, u):
        pred = np.repeat(np.asarray(y0)[:, None, :], u.shape[1], axis=1)
        change(pred)
        return pred
    return predict


@pytest.mark.parametrize("change, problem", [
    (lambda p: p.__setitem__((0, 2, 1), np.nan), "the prediction is nan at window 0, step 3, output 1"),
    (lambda p: p.__setitem__((1, 0, 11), np.inf), "the prediction is inf at window 1, step 1, output 11"),
    # a zero quaternion would score a rotation error of 0 against any truth
    (lambda p: p.__setitem__((slice(None), slice(None), slice(6, 10)), 0.0), "has norm 0"),
    (lambda p: p.__setitem__((slice(None), slice(None), slice(6, 10)), 0.6), "has norm 1.2;"),
])
def test_unscorable_predictions_are_refused(change, problem):
    flight = still_flight("melon_a_run1", 60)
    with pytest.raises(PredictionError, match=re.escape(problem)):
        protocol.evaluate(naive_with(change), [flight], horizon=5)
    y = np.repeat(flight.y[None, :5], 3, axis=0)
    pred = y.copy()
    change(pred)
    with pytest.raises(PredictionError):
        protocol.score(y, pred)


@pytest.mark.parametrize("key, value", [("horizon", 0), ("horizon", -5), ("horizon", 2.5), ("horizon", True),
                                        ("batch_size", 0), ("batch_size", -1), ("batch_size", "8")])
def test_protocol_settings_must_be_whole_numbers_of_at_least_one(key, value):
    flight = still_flight("melon_a_run1", 60)
    with pytest.raises(ConfigError, match=f"{key} must be a whole number >= 1, got {re.escape(repr(value))}"):
        protocol.evaluate(predictors.predictor("naive"), [flight], **{key: value})


def test_a_predictor_cannot_change_the_flight_it_is_scored_on():
    flight = still_flight("melon_a_run1", 60)
    before = flight.y.copy()

    def vandal(y0, u):
        try:
            y0[:] = 0.0  # a predictor that writes to its input
        except ValueError:
            pass
        return np.repeat(np.asarray(before[:len(y0)])[:, None, :], u.shape[1], axis=1)

    protocol.evaluate(vandal, [flight], horizon=5)
    assert np.array_equal(flight.y, before)


def test_template_layout_row_t_holds_the_prediction_started_at_t():
    """A flight whose x is the sample index and a predictor that adds h to x at step h: row t
    of the template frame holds x_pred_h{h} = t + h, the measurement h rows below. Scored the
    template's way (row t against the measurement of row t + h - 1, after dropna) the error is
    1 at every h; one row's shift makes it ours, 0."""
    T, H = 120, 5
    (flight,) = synthetic.synthetic_flights(["melon_x_run1"], T, noise=0.0, seed=0)
    flight.y[:, 0] = np.arange(T, dtype=float)

    def predict(y0, u):
        out = np.repeat(np.asarray(y0)[:, None, :], u.shape[1], axis=1)
        out[:, :, 0] += np.arange(1, u.shape[1] + 1)
        return out

    frame = protocol.template_frame(predict, flight, horizon=H)
    assert list(frame.columns[:14]) == ["t", "x", "y", "z", "vx", "vy", "vz", "qx", "qy", "qz", "qw", "wx", "wy", "wz"]
    assert len(frame.columns) == 14 + 13 * H and "wz_pred_h5" in frame.columns
    assert frame["x_pred_h3"][10] == 13.0 and frame["x_pred_h1"][T - H - 1] == T - H
    assert frame["x_pred_h1"][T - H:].isna().all()

    def template_mae(df, h):
        pred = df[f"x_pred_h{h}"].to_numpy()
        truth = df["x"].shift(-(h - 1)).to_numpy()
        ok = ~np.isnan(pred) & ~np.isnan(truth)
        return np.abs(pred[ok] - truth[ok]).mean()

    shifted = frame.copy()
    pred_cols = [c for c in frame.columns if "_pred_h" in c]
    shifted[pred_cols] = frame[pred_cols].shift(1)
    for h in (1, 3, 5):
        assert template_mae(frame, h) == 1.0
        assert template_mae(shifted, h) == 0.0
