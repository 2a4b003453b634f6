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
