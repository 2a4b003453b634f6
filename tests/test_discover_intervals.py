"""The coefficients' intervals of discovery hold their stated level: a known linear truth under
noise, fitted with the folds and blocks discovery uses, many times over."""

import numpy as np

from nanosysid.discover.stats import half_width as _half_width, hodges_lehmann, jackknife as _jackknife, spread
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


def test_the_spread_over_flights_and_its_interval_cover_the_laws_std_95_percent_of_the_time():
    # 1, 2, 3: deviations -1, 0, 1, so s² = 2 / (3 - 1) = 1
    assert spread(np.array([[1.0], [2.0], [3.0]]))[0] == np.array([1.0])
    # 17 flights (the rig's training set), two channels of stds 0.17 and 0.05, 4000 draws
    rng = np.random.default_rng(5)
    sigma = np.array([0.17, 0.05])
    draws = rng.standard_normal((4000, 17, 2)) * sigma + 0.3
    covered = np.zeros(2)
    for values in draws:
        s, low, high = spread(values)
        assert np.all(low < s) and np.all(s < high)
        covered += (low <= sigma) & (sigma <= high)
    # binomial std of a 95 % rate over 4000 draws: 0.34 %
    assert np.all(np.abs(covered / len(draws) - 0.95) < 0.012), covered / len(draws)


def test_the_quantile_is_students_t_with_a_degree_fewer_than_the_groups():
    # tables: t_0.975 with 9 degrees of freedom is 2.262, with 1 it is 12.706
    assert abs(_half_width(1.0, 10) - 2.262) < 1e-3
    assert abs(_half_width(0.5, 2) - 0.5 * 12.706) < 1e-2


def test_the_gain_per_block_is_the_median_of_the_pairwise_means_not_moved_by_one_wild_block():
    # Walsh averages of (1, 2, 3, -1000), worked by hand: -1000, -499.5, -499, -498.5, 1, 1.5,
    # 2, 2, 2.5, 3; their median is (1 + 1.5) / 2, while the mean is -248.5
    assert hodges_lehmann(np.array([1.0, 2.0, 3.0, -1000.0])) == 1.25
    # for gains drawn around a centre, it estimates the centre (the standard error of a sample's
    # location is 1 / sqrt(400) = 0.05 here)
    rng = np.random.default_rng(3)
    assert abs(hodges_lehmann(rng.normal(2.0, 1.0, 400)) - 2.0) < 0.2


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


def test_the_velocity_from_position_is_the_positions_derivative_free_of_the_estimates_drift():
    # a cubic position: its derivative is exact under a Savitzky-Golay filter of order 3, edges
    # included; the recorded velocity carries a slow 0.1 m/s error the result must not keep
    from nanosysid.dataio import Flight
    from nanosysid.discover.fit import with_position_velocity

    t = np.arange(500) * 0.01
    c = np.array([[0.3, -0.2, 1.0], [0.5, 0.1, -0.4], [-0.05, 0.02, 0.01]])  # t, t², t³ per axis
    y = np.zeros((len(t), 13))
    y[:, 0:3] = 1.0 + t[:, None] * c[0] + t[:, None] ** 2 * c[1] + t[:, None] ** 3 * c[2]
    truth = c[0] + 2 * t[:, None] * c[1] + 3 * t[:, None] ** 2 * c[2]
    y[:, 3:6] = truth + 0.1 * np.sin(2 * np.pi * 0.3 * t)[:, None]
    y[:, 9] = 1.0
    f = Flight("square_20250601_run1", t, np.full((len(t), 4), 2000.0), y, {})
    g = with_position_velocity(f, 15, 3)
    np.testing.assert_allclose(g.y[:, 3:6], truth, atol=1e-9)
    np.testing.assert_array_equal(g.y[:, [0, 1, 2, *range(6, 13)]], y[:, [0, 1, 2, *range(6, 13)]])
    assert np.abs(f.y[:, 3:6] - truth).max() > 0.09  # the flight given is left as it was


def test_the_noise_spectrum_is_white_noise_through_the_filters_and_the_band_is_what_stands_above_it():
    from scipy.signal import savgol_filter

    from nanosysid.discover.fit import noise_spectrum
    from nanosysid.discover.verdicts import _band

    rng = np.random.default_rng(0)
    dt, n, L = 0.01, 256, 200
    # white noise through the derivative filter (a gyro's torque), scaled to unit variance
    x = savgol_filter(rng.normal(size=(400, L)), 15, 3, deriv=1, delta=dt, axis=1)[:, 20:-20]
    x /= x.std()
    w = np.hanning(x.shape[1])
    periodogram = np.mean(np.abs(np.fft.rfft((x - x.mean(axis=1, keepdims=True)) * w, n=n, axis=1)) ** 2, axis=0)
    expected = noise_spectrum(np.array([0.0, 1.0]), 15, 3, dt, n) * (w ** 2).sum()
    band = slice(3, 100)  # away from DC (the mean removed) and the derivative's notch at Nyquist
    np.testing.assert_allclose(periodogram[band], expected[band], rtol=0.25, atol=0.02 * expected.max())
    # a 0.5 Hz torque at a third of the noise's power: its band is where it lies (within the 2 s
    # blocks' resolution, 0.39 Hz bins and a Hann window's main lobe), while the noise alone puts
    # the middle half of the power between about 7 and 16 Hz
    t = np.arange(40 * 200) * dt
    blocks = np.repeat(np.arange(40), 200)
    noise = savgol_filter(rng.normal(size=len(t)), 15, 3, deriv=1, delta=dt)
    noise /= noise.std()
    lo, hi = (float(v) for v in _band(noise + 0.8 * np.sin(2 * np.pi * 0.5 * t), blocks, dt,
                                       np.array([0.0, 1.0]), 15, 3)[:-3].split("-"))
    assert lo <= 0.5 <= hi <= 1.6, (lo, hi)


def test_the_models_name_says_terms_only_where_it_applies_some():
    from nanosysid.discover.records import DiscoveryResult, Finding

    def result(*findings):
        return DiscoveryResult(list(findings), None, None, None, None, None, [], 0.01, 0.25, np.ones(6))

    drag = Finding("named", "induced_drag", ("F_x", "F_y", "F_z"), {}, {})
    fitted = Finding("unnamed", None, ("F_y",), {}, {})
    left_out = Finding("unnamed", None, ("F_y",), {}, {"added": False})
    time = Finding("not a function of the state", None, ("tau_z",), {}, {})
    assert result(drag, fitted, time).name == "physics+induced_drag+terms"
    assert result(drag, left_out, time).name == "physics+induced_drag"
    assert result(time).name == "physics"


def test_a_finding_whose_every_interval_holds_zero_is_not_named():
    from nanosysid.discover.records import Finding
    from nanosysid.discover.verdicts import undetermined

    def finding(name, *cis):
        return Finding("named", name, ("F_x",), {f"c{i}": 0.0 for i in range(len(cis))},
                       {"ci": {f"c{i}": ci for i, ci in enumerate(cis)}})

    spread = finding("rotor_spread", (-0.02, 0.03), (-0.01, 0.0), (-0.4, 0.1), (0.0, 0.0))  # all four hold 0
    drag = finding("induced_drag", (-0.1, 0.5), (0.2, 0.9))       # the second excludes 0
    ground = finding("ground_effect", (1e-9, 1e-3))                # a thin interval just above 0
    delay = finding("input_delay", (0.0, 0.01))                    # starts at the grid's first point
    undetermined([spread, drag, ground, delay])
    assert spread.verdict == "undetermined" and spread.evidence["was"] == "named"
    assert [f.verdict for f in (drag, ground, delay)] == ["named"] * 3


def test_the_rotor_speeds_local_noise_is_read_back_through_the_data_chains_filter():
    # white noise of 5 rad/s for 10 s, then 20 rad/s, on rotors sweeping slowly around hover;
    # once as recorded, once through the zero-phase Butterworth of the data chain (20 Hz, 4th
    # order): both give the white noise's std back, away from the step between the two levels
    from scipy.signal import butter, sosfiltfilt

    from nanosysid.dataio import Flight
    from nanosysid.discover.fit import ChainFilter, input_noise

    rng = np.random.default_rng(11)
    t = np.arange(2000) * 0.01
    slow = 1800.0 + 150.0 * np.sin(2 * np.pi * 0.5 * t)[:, None] * np.array([1.0, -1.0, 0.8, -0.6])
    std = np.where(t < 10.0, 5.0, 20.0)
    noise = rng.standard_normal((len(t), 4)) * std[:, None]
    y = np.zeros((len(t), 13))
    y[:, 9] = 1.0
    sos = butter(4, 20.0, "lowpass", fs=100.0, output="sos")
    for u, chain in ((slow + noise, None), (slow + sosfiltfilt(sos, noise, axis=0), ChainFilter(rotor=20.0))):
        est = input_noise(Flight("random_20250601_run1", t, u, y), chain)
        for lo, hi, truth in ((100, 900, 5.0), (1100, 1900, 20.0)):
            level = np.sqrt(np.mean(est[lo:hi] ** 2))
            assert abs(level / truth - 1) < 0.06, (chain, truth, level)
