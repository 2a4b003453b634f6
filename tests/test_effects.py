"""The library's columns against physics worked out independently: a rigid body with another
inertia, the generic terms' products evaluated directly, the noise floor of pure noise."""

import numpy as np
import pytest
import torch

from nanosysid import effects
from nanosysid.discover.generic import TermLibrary
from nanosysid.vehicle import Vehicle


def _state(rng, n):
    x = np.zeros((n, 13))
    x[:, 0:3] = rng.normal(0, 1, (n, 3)) + [0, 0, 1.5]
    x[:, 3:6] = rng.normal(0, 1.5, (n, 3))
    q = rng.normal(0, 1, (n, 4))
    x[:, 6:10] = q / np.linalg.norm(q, axis=1, keepdims=True)
    x[:, 10:13] = rng.normal(0, 3, (n, 3))
    return x


def _inputs(rng, n):
    """States and rotor speeds (rad/s) of ``n`` random samples, as tensors."""
    return torch.from_numpy(_state(rng, n)), torch.from_numpy(rng.uniform(1500, 2500, (n, 4)))


def test_inertia_columns_are_the_first_order_change_of_the_measured_torque():
    # a body of inertia J + dJ driven by the rotor torque tau: dw/dt = (J + dJ)^-1 (tau - w x (J + dJ) w);
    # the torque measured with the nominal J is J dw/dt + w x J w. Its difference from tau, for a
    # dJ of 1e-3 J, must be the inertia columns times the correction up to second order
    rng = np.random.default_rng(0)
    v = Vehicle()
    x, om = _inputs(rng, 64)
    J = np.array(v.inertia)
    dJ = 1e-3 * J * np.array([1.0, -2.0, 1.5])
    kl = v.k_f * v.arm
    s = om.numpy() ** 2
    tau = np.column_stack([kl * (-s[:, 0] - s[:, 1] + s[:, 2] + s[:, 3]),
                           kl * (-s[:, 0] + s[:, 1] + s[:, 2] - s[:, 3]),
                           v.k_m * (-s[:, 0] + s[:, 1] - s[:, 2] + s[:, 3])])
    w = x[:, 10:13].numpy()
    Jt = J + dJ
    w_dot = (tau - np.cross(w, Jt * w)) / Jt
    residual = J * w_dot + np.cross(w, J * w) - tau
    cols = effects.features(["inertia"], x, om, torch.zeros_like(om), v).numpy()  # (n, 6, 3)
    c = dJ * J / (J + dJ)  # the columns' coefficient (the entry's physical map inverted by hand)
    predicted = cols[:, 3:, :] @ c
    assert np.abs(predicted - residual).max() < 1e-2 * np.abs(residual).max()
    assert effects.LIBRARY["inertia"].values(c, v) == pytest.approx(dJ.tolist(), rel=1e-9)


def test_an_inertia_correction_never_gives_a_body_of_no_inertia():
    # a coefficient c of the acceleration column says the body turns (J - c) / J as fast as the
    # nominal one; c >= J would be a body of no or negative inertia. Worked by hand: c = J / 2 is a
    # body twice as heavy (dJ = J); c = J, and anything beyond, the heaviest allowed (5 J: dJ = 4 J);
    # c = -10 J the lightest (J / 5: dJ = -0.8 J)
    v = Vehicle()
    J = np.array(v.inertia)
    values = effects.LIBRARY["inertia"].values
    assert values([0.5 * J[0], J[1], -10 * J[2]], v) == pytest.approx([J[0], 4 * J[1], -0.8 * J[2]], rel=1e-12)
    assert values([2 * J[0], 0.0, 0.0], v) == pytest.approx([4 * J[0], 0.0, 0.0], rel=1e-12)
    bodies = J + np.array(values([1.0, 1.0, -1.0], v))  # far outside on both sides
    assert np.all(bodies > 0) and bodies == pytest.approx([5 * J[0], 5 * J[1], 0.2 * J[2]], rel=1e-12)


def test_rotor_spread_is_each_rotor_off_by_its_own_share():
    # rotors of k_F (1 + d_i), k_M (1 + d_i) with the d_i averaging zero: the extra thrust and
    # torques, rotor by rotor from the mixer written out by hand (rotors at (+-L/sqrt2, +-L/sqrt2),
    # spins + - + -), are the entry's columns times the coefficients whose physical values are d
    rng = np.random.default_rng(2)
    v = Vehicle()
    x, om = _inputs(rng, 32)
    d = np.array([0.03, -0.02, 0.025, -0.035])
    d -= d.mean()
    s = om.numpy() ** 2 * d
    kl = v.k_f * v.arm
    extra = np.column_stack([v.k_f * s.sum(1), kl * (-s[:, 0] - s[:, 1] + s[:, 2] + s[:, 3]),
                             kl * (-s[:, 0] + s[:, 1] + s[:, 2] - s[:, 3]), v.k_m * (-s[:, 0] + s[:, 1] - s[:, 2] + s[:, 3])])
    e = effects.LIBRARY["rotor_spread"]
    # the coefficients whose physical values are d: the map is linear, solve it column by column
    basis = np.array([e.values(row, v) for row in np.eye(e.n_columns)]).T  # (4, columns)
    a, *_ = np.linalg.lstsq(basis, d, rcond=None)
    assert e.values(a, v) == pytest.approx(d.tolist(), abs=1e-12)
    cols = effects.features(["rotor_spread"], x, om, torch.zeros_like(om), v).numpy()  # (n, 6, 3)
    assert np.allclose(cols[:, 2:, :] @ a, extra, rtol=1e-9, atol=1e-12 * np.abs(extra).max())
    assert np.allclose(cols[:, :2, :], 0.0)


def test_generic_terms_back_in_raw_products_are_the_same_function():
    rng = np.random.default_rng(1)
    names = list(effects.TERM_SIGNALS)
    sig = rng.normal([1, 0, 0, 0, 0, 0, 0.4, 1.5][:len(names)], 1.0, (500, len(names)))
    lib = TermLibrary(sig)
    coef = np.zeros(len(lib.names))
    coef[rng.choice(len(coef), 6, replace=False)] = rng.normal(0, 1, 6)
    raw = lib.raw(coef)
    direct = np.zeros(len(sig))
    for k, name in enumerate(lib.names):
        if raw[k]:
            term = np.ones(len(sig))
            for f in ([] if name == "1" else name.split("*")):
                term = term * sig[:, names.index(f)]
            direct += raw[k] * term
    assert np.allclose(lib(sig) @ coef, direct, rtol=1e-9, atol=1e-9)


def test_physical_signs_and_kinds():
    # a drag coefficient is positive; corrections change the vehicle, they add no wrench
    for name in ("linear_drag", "induced_drag", "quadratic_drag", "rate_damping", "rotor_gyro"):
        assert all(s == 1 for s in effects.LIBRARY[name].signs), name
    assert {n for n, e in effects.LIBRARY.items() if e.kind == "correction"} == {"inertia", "arm"}
    v = effects.apply_corrections(Vehicle(), {"inertia": [1e-6, 2e-6, 3e-6], "arm": [0.001]})
    assert v.inertia == pytest.approx((2.4951e-5, 2.5951e-5, 3.5347e-5)) and v.arm == pytest.approx(0.03635)


def test_the_columns_side_by_side_times_theta_are_the_c_paths_wrench_of_every_entry():
    # effects.wrench is the generated C's path: each entry's force and torque summed scalar by
    # scalar from its own columns; the regression's and the rollout's path lays every entry's
    # columns into one (6, P) matrix, so a column in the wrong row or place, a constant lost or
    # a zero that is not one shows as a different wrench
    rng = np.random.default_rng(7)
    x, om = _inputs(rng, 40)
    om_dot = torch.from_numpy(rng.normal(0, 2000, (40, 4)))
    v = Vehicle()
    names = [n for n, e in effects.LIBRARY.items() if e.columns is not None]
    names += [effects.NOMINAL.name, effects.term_name("F_x", "1"), effects.term_name("tau_y", "v_x*w_z")]
    theta = rng.normal(0, 1, sum(effects.entry(n).n_columns for n in names))
    expected = torch.zeros(40, 6, dtype=torch.float64)
    sg = effects.signals(x, om, om_dot)
    for name, th in effects.split_coefficients(names, theta).items():
        force, torque = effects.wrench(name, th, sg, v)
        for c, total in enumerate(force + torque):
            expected[:, c] += total
    got = effects.features(names, x, om, om_dot, v) @ torch.from_numpy(theta)
    assert torch.allclose(got, expected, rtol=1e-12, atol=1e-12 * expected.abs().max().item())
    one = effects.features(names, x[3], om[3], om_dot[3], v)  # one sample, unbatched
    assert torch.allclose(one @ torch.from_numpy(theta), expected[3], rtol=1e-12, atol=1e-12 * expected.abs().max().item())


def _mixer(v, s):
    """Thrust and roll, pitch, yaw torques of squares ``s (n, 4)``, the rotor layout worked out by hand."""
    kl = v.k_f * v.arm
    return np.column_stack([v.k_f * s.sum(axis=1), kl * (-s[:, 0] - s[:, 1] + s[:, 2] + s[:, 3]),
                            kl * (-s[:, 0] + s[:, 1] + s[:, 2] - s[:, 3]),
                            v.k_m * (-s[:, 0] + s[:, 1] - s[:, 2] + s[:, 3])])


def test_slow_actuation_is_the_mixer_of_each_rotors_lag_behind_a_speed_step():
    # rotor speeds stepping at t = 0 from rest at s0 to s1: a first-order lag of time constant T
    # reads s1 + (s0 - s1) exp(-t / T) at every sample (the exact response to a held step)
    v = Vehicle()
    dt, n = 0.01, 300
    s0, s1 = np.array([1.6e6, 2.0e6, 1.8e6, 2.2e6]), np.array([2.5e6, 1.9e6, 2.4e6, 2.0e6])
    s = np.where(np.arange(n)[:, None] >= 1, s1, s0)
    om = torch.from_numpy(np.sqrt(s))[None]
    slow = effects.slow_squares(om, dt)[0].numpy()  # (n, 4 K)
    t = (np.arange(n) - 1) * dt
    for k, T in enumerate(effects.SLOW_TIMES):
        expected = np.where(t[:, None] >= 0, s1 + (s0 - s1) * np.exp(-(t[:, None] + dt) / T), s0)
        assert np.allclose(slow[:, 4 * k:4 * k + 4], expected, rtol=1e-9)
    x = torch.zeros(n, 13, dtype=torch.float64)
    x[:, 9] = 1.0
    cols = effects.features(["slow_actuation"], x, om[0], torch.zeros_like(om[0]), v,
                            s_slow=torch.from_numpy(slow)).numpy()  # (n, 6, K)
    for k in range(len(effects.SLOW_TIMES)):
        lag = slow[:, 4 * k:4 * k + 4] - s
        assert np.allclose(cols[:, 2:, k], _mixer(v, lag), rtol=1e-9, atol=1e-12)
        assert np.all(cols[:, :2, k] == 0)
    # without the history the entry adds nothing (a model fed no history must not invent one)
    assert np.all(effects.features(["slow_actuation"], x, om[0], torch.zeros_like(om[0]), v).numpy() == 0)
    # read against a k_F that took c_k of each lag: k_F (s + g (LP - (1 + c) s)) on the thrust and
    # the roll/pitch torques; the yaw torque's k_M is a yaw sweep's, its columns as they were
    c = (-0.01, -0.03, -0.05)
    held = effects.features(["slow_actuation"], x, om[0], torch.zeros_like(om[0]), v, s_slow=torch.from_numpy(slow),
                            lag_in_k_f=c).numpy()
    for k in range(len(effects.SLOW_TIMES)):
        lag = slow[:, 4 * k:4 * k + 4] - s
        assert np.allclose(held[:, 2:5, k], _mixer(v, lag - c[k] * s)[:, :3], rtol=1e-9, atol=1e-12)
        assert np.allclose(held[:, 5, k], _mixer(v, lag)[:, 3], rtol=1e-9, atol=1e-12)


def test_what_least_squares_of_the_thrust_takes_of_a_lag_is_its_in_phase_loss_over_the_mean_square():
    # S = A + B sin(w t) through y_n = (1 - a) y_(n-1) + a x_n, a = 1 - exp(-dt / T): its sine comes
    # out times H = a / (1 - (1 - a) exp(-i w dt)), so <S, LP(S) - S> / n = B^2 / 2 (Re H - 1)
    # and <S, S> / n = A^2 + B^2 / 2 (whole periods; the start's transient dies within 5 T)
    dt, A, B, f = 0.01, 8.0e6, 2.0e6, 0.5
    t = np.arange(0, 4000.0, dt)
    S = A + B * np.sin(2 * np.pi * f * t)
    om = np.repeat(np.sqrt(S / 4)[:, None], 4, axis=1)
    got = effects.lag_in_k_f([om[:200000], om[200000:]], dt)
    for T, c in zip(effects.SLOW_TIMES, got):
        a = 1 - np.exp(-dt / T)
        H = a / (1 - (1 - a) * np.exp(-1j * 2 * np.pi * f * dt))
        assert c == pytest.approx(B ** 2 / 2 * (H.real - 1) / (A ** 2 + B ** 2 / 2), rel=0.003)
    # and the rotors' own k_F undoes it to first order
    assert effects.lagged_k_f(1.0, [0.0, 0.5, 0.0], got) == pytest.approx(1 - 0.5 * got[1])


def test_a_slow_actuation_is_a_lag_only_where_its_step_response_never_falls_back():
    # half the wrench through the 0.3 s lag: 1 - 0.5 exp(-t / 0.3) rises from 0.5 to 1 and never falls
    rise, fall = effects.lag_shape([0.0, 0.5, 0.0])
    assert rise == pytest.approx(0.5, abs=1e-3) and fall == 0.0
    assert effects.LIBRARY["slow_actuation"].shape([0.0, 0.5, 0.0])
    # a fast share minus a slow one: 1 - 0.5 exp(-10 t) + 0.5 exp(-t) peaks where 5 exp(-10 t) =
    # 0.5 exp(-t), t = ln(10) / 9, at 1 + 0.5 (10^(-1/9) - 10^(-10/9)) = 1.3485, and falls back to
    # 1 + 0.5 exp(-5) by t = 5 s: a band-pass, no lag
    peak = 0.5 * (10 ** (-1 / 9) - 10 ** (-10 / 9))
    rise, fall = effects.lag_shape([0.5, 0.0, -0.5])
    assert rise == pytest.approx(peak, abs=1e-4) and fall == pytest.approx(peak - 0.5 * np.exp(-5), abs=1e-4)
    assert not effects.LIBRARY["slow_actuation"].shape([0.5, 0.0, -0.5])
    # a lead (the wrench ahead of k Omega^2) falls from the start: no lag either
    assert not effects.LIBRARY["slow_actuation"].shape([0.0, -0.3, 0.0])


def test_a_window_continues_the_flights_lag_where_it_is_given_its_state():
    rng = np.random.default_rng(3)
    om = torch.from_numpy(rng.uniform(1500, 2500, (2, 400, 4)))
    whole = effects.slow_squares(om, 0.01)  # the flight's filter (a whole flight: scipy's recursion)
    tail = effects.slow_squares(om[:, 300:], 0.01, start=whole[:, 299])  # a window given the state before it
    assert torch.allclose(tail, whole[:, 300:], rtol=1e-12)


def test_battery_thrust_scales_the_rotor_wrench_with_the_voltage_off_its_reference():
    rng = np.random.default_rng(4)
    v = Vehicle()
    x, om = _inputs(rng, 16)
    vbat = torch.from_numpy(rng.uniform(3.3, 4.2, 16))
    cols = effects.features(["battery_thrust"], x, om, torch.zeros_like(om), v, vbat=vbat).numpy()[..., 0]
    dv = vbat.numpy()[:, None] - 3.7  # a 1S LiPo's mid charge
    assert np.allclose(cols[:, 2:], dv * _mixer(v, om.numpy() ** 2), rtol=1e-12)
    assert np.all(cols[:, :2] == 0)


def test_the_library_rules_judge_a_lag_a_spread_and_a_sign_by_hand():
    vehicle, lag = Vehicle(), effects.entry("slow_actuation")
    # a quarter of the wrench 0.1 s late: a lag; a share of -1.2 of the wrench: beyond the bound of 1
    assert lag.implausible([0.25, 0.0, 0.0], vehicle, [0.05] * 3) == ""
    assert lag.implausible([0.8, -1.2, 0.9], vehicle, [0.4] * 3) == "g_0.3s beyond the entry's bound (1)"
    # shares -0.5 at 0.1 s and +1 at 1 s: the step response 1 + 0.5 e^(-t/0.1) - e^(-t) starts at
    # 0.5, dips to 0.247 at t = ln(5)/9 = 0.179 s and rises to 1 - e^(-5) = 0.993: it falls back by
    # 0.253, half its rise of 0.493, where a lag may fall back by a quarter at most
    assert lag.implausible([-0.5, 0.0, 1.0], vehicle, [0.1] * 3).startswith("its coefficients")
    assert lag.implausible([-0.5, 0.0, 1.0], vehicle, [0.1] * 3, shape=False) == ""  # within the bound
    # rotors 30 % apart: beyond rotor_spread's bound of 25 %
    assert "beyond" in effects.entry("rotor_spread").implausible([0.3, 0.0, 0.0], vehicle, [0.01] * 3)
    assert effects.entry("drag_moment").implausible([-8e-4], vehicle, [1e-5]) == ""  # either sign: above or below
    # a ground effect of c = 1e-3 m² is 21 times (27.5 mm / 4)² = 4.73e-5 m², within the bound of 25;
    # 3e-3 m² (63 times: 13 % more thrust at 15 cm) is beyond it
    assert effects.entry("ground_effect").implausible([1e-3], vehicle, [1e-4]) == ""
    assert effects.entry("ground_effect").implausible([3e-3], vehicle, [1e-4]) == "c beyond the entry's bound (25)"
    # a drag coefficient 3 intervals below zero has the wrong sign; 0.5 of one below zero is noise
    assert effects.entry("induced_drag").implausible([-3e-6, 1e-6], vehicle, [1e-6, 1e-6]).startswith("K_xy below")
    assert effects.entry("induced_drag").implausible([-0.5e-6, 1e-6], vehicle, [1e-6, 1e-6]) == ""
    assert effects.entry("induced_drag").implausible([-3e-6, 1e-6], vehicle) == ""  # signs need an interval
