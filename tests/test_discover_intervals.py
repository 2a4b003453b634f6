"""The coefficients' intervals of discovery hold their stated level: a known linear truth under
noise, fitted with the folds and blocks discovery uses, many times over."""

import numpy as np

from nanosysid.discover.stats import half_width as _half_width, jackknife as _jackknife
from nanosysid.discover.fit import Grams


def test_a_95_percent_interval_covers_the_truth_95_percent_of_the_time():
    rng = np.random.default_rng(3)
    blocks, per_block, folds, trials = 40, 25, 10, 2000
    theta = np.array([0.7, -0.2])
    ids = np.repeat(np.arange(blocks), per_block)
    weights = np.ones(6)
    cols = np.arange(2)
    covered = 0
    for _ in range(trials):
        X = np.zeros((len(ids), 6, 2))
        X[:, 0] = rng.standard_normal((len(ids), 2))
        # the noise shares a level within each block (a slow disturbance), so samples are not
        # independent but blocks are
        noise = rng.standard_normal(len(ids)) + rng.standard_normal(blocks)[ids]
        y = np.zeros((len(ids), 6))
        y[:, 0] = X[:, 0] @ theta + noise
        g = Grams(X, y, weights, ids, folds)
        estimate = g.solve(cols)
        _, per_fold = g.heldout(cols)
        half = _half_width(_jackknife(per_fold)[0], folds)
        covered += abs(estimate[0] - theta[0]) <= half
    # binomial std of the share at 95 %: 0.5 %; the normal quantile with 10 folds covers 92 %
    assert 0.935 <= covered / trials <= 0.965, covered / trials


def test_the_quantile_is_students_t_with_a_degree_fewer_than_the_groups():
    # tables: t_0.975 with 9 degrees of freedom is 2.262, with 1 it is 12.706
    assert abs(_half_width(1.0, 10) - 2.262) < 1e-3
    assert abs(_half_width(0.5, 2) - 0.5 * 12.706) < 1e-2


def test_a_coefficient_held_fixed_is_the_fit_of_what_it_leaves():
    # holding column 1 at c is the least-squares fit of y - c x_1 on the other columns, computed
    # here from the samples themselves; its held-out error is that of the residual left
    rng = np.random.default_rng(5)
    n, folds = 400, 4
    ids = np.repeat(np.arange(20), n // 20)
    X = np.zeros((n, 6, 3))
    X[:, 2] = rng.standard_normal((n, 3))
    X[:, 5, 1] = rng.standard_normal(n)  # column 1 also acts on another channel
    y = np.zeros((n, 6))
    y[:, 2] = X[:, 2] @ np.array([0.5, -1.0, 2.0]) + 0.1 * rng.standard_normal(n)
    y[:, 5] = -1.0 * X[:, 5, 1] + 0.1 * rng.standard_normal(n)
    weights = np.array([1.0, 1.0, 2.0, 1.0, 1.0, 0.5])
    c = -0.8
    g = Grams(X, y, weights, ids, folds).fixed(1, c)
    cols = np.arange(3)
    rest = (y - c * X[..., 1]) * weights  # (n, 6)
    A = (X[..., [0, 2]] * weights[None, :, None]).reshape(-1, 2)
    expected = np.linalg.lstsq(A, rest.reshape(-1), rcond=None)[0]
    theta = g.solve(cols)
    assert theta[1] == c
    np.testing.assert_allclose(theta[[0, 2]], expected, rtol=1e-10)
    sse, per_fold = g.heldout(cols)
    assert np.all(per_fold[:, 1] == c)
    k = 0  # the blocks of fold 0, held out of the fit on the others
    test = np.isin(ids, np.flatnonzero(np.arange(20) % folds == k))
    th = np.linalg.lstsq(A[np.repeat(~test, 6)], rest[~test].reshape(-1), rcond=None)[0]
    left = rest[test] - (X[test][..., [0, 2]] * weights[None, :, None]) @ th
    np.testing.assert_allclose(sse[np.arange(20) % folds == k].sum(), (left ** 2).sum(), rtol=1e-9)
