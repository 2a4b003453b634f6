"""The flight simulator: references, controller, hidden effects, determinism, oracle."""

import dataclasses
import functools
import math

import numpy as np
import pytest
import torch

from nanosysid import predictors, protocol, sim, so3
from nanosysid.dataio import write_flight_csv
from nanosysid.errors import ConfigError, PredictionError
from nanosysid.sim import world as fx
from nanosysid.sim.simulator import NoiseConfig, SimConfig, simulate, simulate_raw
from nanosysid.sim.trajectories import Reference, make_reference
from nanosysid.vehicle import Vehicle

V = Vehicle()

# short flights keep the suite fast; the Melon keeps its geometry and rates
SHORT = SimConfig.from_mapping({
    "preroll": 1.0,
    "trajectories": {"melon": {"duration": 6.0, "circle_time": 4.0, "return_time": 1.5, "ramp_time": 0.15}},
})


def constant_push(t, x, omega, omega_dot):
    """A 10 mN force along body x."""
    force = torch.zeros_like(x[..., :3])
    force[..., 0] = 0.01
    return force, torch.zeros_like(force)


def wavering_push(t, x, omega, omega_dot):
    """A vertical force and a roll torque, each a sinusoid of time."""
    force = torch.zeros_like(x[..., :3])
    force[..., 2] = 0.02 * torch.sin(2.0 * t)
    torque = torch.zeros_like(force)
    torque[..., 0] = 1e-4 * torch.cos(3.0 * t)
    return force, torque


# The short noise-free Melons the tests below compare, each in its own world, simulated as one
# batch: a flight is the same alone or in any batch (test_a_flight_is_the_same_alone_or_in_a_batch...).
MELONS = {
    "none": sim.FlightSpec("melon", effects={}),
    **{e: sim.FlightSpec("melon", effects={e: 1.0}) for e in sim.EFFECTS},
    "drag_com_asymmetry": sim.FlightSpec("melon", effects={"rotor_drag": 1.0, "com_offset": 1.0,
                                                           "motor_asymmetry": 1.0}),
    "pushed": sim.FlightSpec("melon", effects={}, extra_wrench=constant_push),
    "turbulence_wavering": sim.FlightSpec("melon", effects={"turbulence": 1.0}, seed=4, extra_wrench=wavering_push),
}


@pytest.fixture(scope="module")
def melons():
    return dict(zip(MELONS, simulate(list(MELONS.values()), cfg=SHORT, noise=False, progress=False)))


def sample(ref, dt=0.01):
    t = np.arange(0, ref.duration + 1e-9, dt)
    return (t, *ref.pva(t))


# ---- references -------------------------------------------------------------------------


def test_square_reference():
    ref = make_reference("square")
    t, p, v, a = sample(ref)
    assert ref.duration == 19.0
    # rest at the corners: the end of every 1 s move and during the 1 s holds
    for k in range(9):
        hold = (t > 2 * k + 1.05) & (t < 2 * k + 1.95)
        assert np.abs(v[hold]).max() < 1e-9
    corners = p[np.isin(np.round(t, 2), [1.5, 3.5, 5.5, 7.5])]
    assert np.allclose(np.abs(corners[:, :2]), 0.5) and np.allclose(corners[:, 2], 1.0)
    assert np.isclose(p[np.round(t, 2) == 11.5][0, 2], 2.0)  # upper plane 1 m higher
    assert np.isclose(p[-1, 2], 1.0) and np.allclose(v[-1], 0)  # back at the starting height
    # minimum snap over 1 m in 1 s: peak speed 35/16 m/s, zero jerk at the ends
    assert np.isclose(np.linalg.norm(v, axis=1).max(), 35 / 16, rtol=1e-3)


def test_random_reference():
    ref = make_reference("random", box=(1.0, 1.0, 0.5), seed=3)
    t, p, v, a = sample(ref)
    assert ref.duration == 60.0
    knots = p[np.isin(np.round(t, 6), np.round(np.linspace(0, 60, 52), 2))]
    # waypoints (the knot values) lie in the box centred at (0, 0, 1.5)
    wps = make_reference("random", box=(1.0, 1.0, 0.5), seed=3).pva(np.linspace(0, 60, 52))[0]
    assert np.all(np.abs(wps - [0, 0, 1.5]) <= [0.5, 0.5, 0.25])
    assert len(knots) > 40
    assert np.allclose(v[0], 0) and np.allclose(v[-1], 0)  # clamped ends
    same = make_reference("random", box=(1.0, 1.0, 0.5), seed=3).pva(t)[0]
    other = make_reference("random", box=(1.0, 1.0, 0.5), seed=4).pva(t)[0]
    assert np.array_equal(same, p) and not np.allclose(other, p)


def test_random_reference_through_given_waypoints():
    # a logged reference's waypoints: the path passes through each at its knot (20 s apart over
    # 60 s) and stands still at both ends; the seed and the box no longer matter
    points = [[0.0, 0.0, 1.0], [1.0, -0.5, 1.5], [-1.0, 0.5, 2.0], [0.2, 0.1, 1.2]]
    ref = make_reference("random", points=points, seed=5, box=(0.1, 0.1, 0.1))
    p, v, _ = ref.pva(np.array([0.0, 20.0, 40.0, 60.0]))
    assert np.allclose(p, points) and np.allclose(v[[0, -1]], 0)
    with pytest.raises(ConfigError, match="random.points"):
        make_reference("random", points=[[0.0, 0.0]])


def test_melon_reference():
    ref = make_reference("melon", ramp_time=0.0)
    t, p, v, a = sample(ref)
    assert ref.duration == 65.0
    circ = t < 55.0
    d = p[circ] - [0, 0, 1.5]
    assert np.allclose(np.linalg.norm(d, axis=1), 0.75)  # radius
    # the circle's plane contains the x axis and turns about it at 0.4 rad/s
    tt = t[circ][1:]
    plane_angle = np.arctan2(-d[1:, 1], d[1:, 2])
    k = np.abs(np.sin(2.5 * tt)) > 0.3
    assert np.allclose(np.sin(2 * (plane_angle[k] - 0.4 * tt[k])), 0, atol=1e-6)
    # circling rate 2.5 rad/s: the local angle advances by 2.5 rad per second
    assert np.isclose(np.arccos(d[100, 0] / 0.75), (2.5 * 1.0) % (2 * np.pi), atol=1e-6) or np.isclose(
        np.arccos(d[100, 0] / 0.75), 2 * np.pi - (2.5 % (2 * np.pi)), atol=1e-6)
    assert np.allclose(p[-1], [0, 0, 1.5]) and np.allclose(v[-1], 0)  # back at the centre, at rest
    assert np.abs(np.diff(v[1:], axis=0)).max() < 0.1  # no velocity jump after the start


def test_melon_circling_rate_rises_as_the_rigs_reference_did():
    # the rig's Melon: the rate rising linearly from 1.5 to 2.5 rad/s over 60 s, so the local
    # angle is 1.5 t + t^2 / 120, and x (r cos of it) peaks where that angle is 2 pi n
    ref = make_reference("melon", omega_start=1.5, omega_circle=2.5, omega_plane=0.2, circle_time=60.0,
                         return_time=4.0, ramp_time=0.0)
    t = np.arange(0, 60, 0.001)
    x = ref.pva(t)[0][:, 0]
    inner = (x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:])
    peaks = t[1:-1][inner]
    n = np.arange(1, len(peaks) + 1)
    expected = 60 * (-1.5 + np.sqrt(1.5**2 + 2 * np.pi * n / 30))
    # 120 rad in all: 19 whole turns
    assert len(peaks) == 19 and np.allclose(peaks, expected, atol=2e-3)
    # the speed on the circle is the radius times the rate where the plane's turn adds nothing
    # (x at its peak: the point on the turning axis)
    v = ref.pva(peaks)[1]
    assert np.allclose(np.linalg.norm(v, axis=1), 0.75 * (1.5 + peaks / 60), rtol=1e-3)


def test_melon_started_from_the_centre_holds_the_centre_until_it_jumps_onto_the_circle():
    # the rig's Melon: a hover at the centre, then the setpoint on the circle's first point, the
    # local (r, 0, 0) that the plane's turn about x leaves where it is: centre + (0.75, 0, 0)
    centre = (0.0, 0.0, 1.25)
    ref = make_reference("melon", center=centre, start_from_centre=True)
    p, v, a = ref.pva(np.array([-5.0, -0.01, 0.0, 10.0]))
    assert np.allclose(p[:2], centre) and np.allclose(v[:3], 0) and np.allclose(a[:3], 0)
    assert np.allclose(p[2], [0.75, 0.0, 1.25])
    # the same flight after t = 0, and without the option the hover is on the circle already
    plain = make_reference("melon", center=centre)
    assert np.array_equal(plain.pva(np.array([10.0]))[0], p[3:]) and np.allclose(plain.pva(np.array([-5.0]))[0], p[2])
    # from the rig's takeoff height: the hover 0.7 m below the centre, the same jump's target
    low = make_reference("melon", center=centre, start_from_centre=True, start_height=0.55)
    q = low.pva(np.array([-5.0, 0.0]))[0]
    assert np.allclose(q[0], [0.0, 0.0, 0.55]) and np.allclose(q[1], p[2])


def test_chirp_reference():
    ref = make_reference("chirp")
    t, p, v, a = sample(ref)
    assert ref.duration == 60.0
    assert np.allclose(p.max(axis=0) - p.min(axis=0), 1.0, atol=1e-3)  # 0.5 m amplitude per axis
    # instantaneous frequency from successive minima of x: 0.1 Hz at the start, 0.5 Hz at the end
    x = p[:, 0]
    minima = t[1:-1][(x[1:-1] < x[:-2]) & (x[1:-1] <= x[2:])]
    periods = np.diff(minima)
    f_mid = 1 / periods
    t_mid = minima[:-1] + periods / 2
    assert np.allclose(f_mid, 0.1 + 0.4 * t_mid / 60, rtol=0.02)
    assert np.allclose(v[0], 0) and np.allclose(v[-1], 0, atol=1e-9)


# ---- controller ---------------------------------------------------------------------------


def test_controller_hovers_and_tracks_a_step():
    def pva(t):
        p = np.where((t < 1.0)[:, None], [0.0, 0.0, 1.0], [0.3, -0.2, 1.2])
        return p, np.zeros_like(p), np.zeros_like(p)

    step = Reference("step", 5.0, pva)
    cfg = SimConfig.from_mapping({"preroll": 1.0, "initial_offset": 0.0})
    f = simulate([sim.FlightSpec(step, 1, effects={}, name="step_t_run1")], cfg=cfg, noise=False, progress=False)[0]
    p = f.y[:, :3]
    assert np.abs(p[:100] - [0, 0, 1.0]).max() < 1e-3  # hover holds still
    assert np.abs(p[-50:] - [0.3, -0.2, 1.2]).max() < 0.02  # settled on the step within 4 s
    overshoot = (p[100:, 0] - 0.3).max()
    assert overshoot < 0.5 * 0.3
    tilt = np.degrees(np.arccos(so3.quat_to_rotmat(torch.from_numpy(f.y[:, 6:10]))[:, 2, 2].numpy()))
    assert tilt.max() < 45


# ---- hidden effects -----------------------------------------------------------------------


def state(v=(0, 0, 0), w=(0, 0, 0)):
    x = torch.zeros(1, 13, dtype=torch.float64)
    x[0, 3:6] = torch.tensor(v, dtype=torch.float64)
    x[0, 9] = 1.0
    x[0, 10:13] = torch.tensor(w, dtype=torch.float64)
    return x


HOVER = torch.full((1, 4), V.hover_speed, dtype=torch.float64)
NO_ACC = torch.zeros(1, 4, dtype=torch.float64)


def wrench(name, x=None, om=HOVER, om_dot=NO_ACC):
    return fx.World({name: 1.0}).wrench(state() if x is None else x, om, om_dot, V)


def test_rotor_drag_opposes_body_velocity_and_pitches_the_nose_up():
    """Worked by hand: at hover the four rotors turn at sqrt(0.045 * 9.81 / (4 * 3.72e-8)) =
    1722.42 rad/s, sum 6889.69 rad/s. Flying forward at 1 m/s: F_x = -2.8e-6 * 6889.69 =
    -1.92911e-2 N (0.43 1/s deceleration), acting at the hubs 8 mm above the centre of mass:
    tau_y = h F_x = -1.54329e-4 N m (nose up), nothing about x or z."""
    f, t = wrench("rotor_drag", state(v=(1.0, 0, 0)))
    assert torch.allclose(f[0], torch.tensor([-1.92911e-2, 0, 0], dtype=torch.float64), rtol=1e-4, atol=1e-15)
    assert torch.allclose(t[0], torch.tensor([0, -1.54329e-4, 0], dtype=torch.float64), rtol=1e-4, atol=1e-15)
    f2, _ = wrench("rotor_drag", state(v=(2.0, 0, 0)))
    assert torch.isclose(f2[0, 0], 2 * f[0, 0])  # linear in speed


def test_rotor_drag_of_each_rotor_damps_a_roll():
    """Worked by hand: rolling at 1 rad/s in hover, rotor i at (x_i, y_i, h) moves at w x r_i =
    (0, -h, y_i): the rotors on the side going down meet air from below (axial inflow) and lose
    thrust, F_i = Omega (0, K_y h, -K_z y_i). Summed: F_y = 6889.69 * 2.8e-6 * 0.008 = 1.54329e-4 N,
    tau_x = -sum Omega (K_z y_i^2 + K_y h^2) = -6889.69 (2e-6 * 0.03535^2 + 2.8e-6 * 0.008^2)
    = -1.84537e-5 N m: a damping torque."""
    f, t = wrench("rotor_drag", state(w=(1.0, 0, 0)))
    assert torch.allclose(f[0], torch.tensor([0, 1.54329e-4, 0], dtype=torch.float64), rtol=1e-4, atol=1e-15)
    assert torch.allclose(t[0], torch.tensor([-1.84537e-5, 0, 0], dtype=torch.float64), rtol=1e-4, atol=1e-15)


def test_body_drag_is_quadratic():
    f1, _ = wrench("body_drag", state(v=(0, -1.0, 0)))
    f2, _ = wrench("body_drag", state(v=(0, -2.0, 0)))
    assert f1[0, 1] > 0 and torch.isclose(f2[0, 1], 4 * f1[0, 1]) and 1e-4 < f1[0, 1] < 1e-2


def test_com_offset_gives_a_thrust_torque():
    """Worked by hand: the centre of mass 1.5 mm ahead of and 1.0 mm right of the rotors' centre,
    the hover thrust T = 0.045 kg * 9.81 = 0.44145 N acts 1.5 mm behind it (nose-heavy: the nose
    drops, a positive torque about +y) and 1.0 mm to its left (the right side drops, a positive
    torque about +x): tau = (1.0e-3 T, 1.5e-3 T, 0) = (4.4145e-4, 6.62175e-4, 0) N m."""
    assert fx.COM_OFFSET == (1.5e-3, -1.0e-3, 0.0)
    _, t = wrench("com_offset")
    assert torch.allclose(t[0], torch.tensor([4.4145e-4, 6.62175e-4, 0.0], dtype=torch.float64), rtol=1e-9, atol=1e-15)


def test_motor_asymmetry_keeps_collective_thrust_and_tilts():
    """Worked by hand: at hover each rotor gives T/4 = 0.1103625 N times (1 + d_i), d = (+3.0,
    -2.0, +2.5, -3.5) %, at (x, y) = L (+1, -1), (-1, -1), (-1, +1), (+1, +1), L = 35.35 mm:
    tau_x = sum y_i F_i = L 0.1103625 (-d1 - d2 + d3 + d4) = -7.80262875e-5 N m,
    tau_y = -sum x_i F_i = -L 0.1103625 (d1 - d2 - d3 + d4) = +3.901314375e-5 N m;
    each rotor's drag torque k_M (1 + d_i) Omega^2 = (2.1177e-10 / 3.72e-8) 0.1103625 (1 + d_i) =
    6.2826523e-4 (1 + d_i) N m turns the body against its spin (M1, M3 counter-clockwise):
    tau_z = -(d1 - d2 + d3 - d4) 6.2826523e-4 = -6.9109176e-5 N m."""
    assert fx.MOTOR_ASYMMETRY == (0.030, -0.020, 0.025, -0.035)
    f, t = wrench("motor_asymmetry")
    assert abs(f[0, 2]) < 1e-12  # zero-mean spread: hover thrust unchanged
    expected = torch.tensor([-7.80262875e-5, 3.901314375e-5, -6.9109176e-05], dtype=torch.float64)
    assert torch.allclose(t[0], expected, rtol=1e-6, atol=0)


def test_rotor_inertia_yaw_reaction_and_gyroscopic_torque():
    spin_up = torch.tensor([[1e4, 0, 0, 0]], dtype=torch.float64)  # M1 (counter-clockwise) speeds up
    _, t = wrench("rotor_inertia", om_dot=spin_up)
    assert t[0, 2] < 0 and math.isclose(-t[0, 2].item(), fx.ROTOR_INERTIA * 1e4)
    om = torch.tensor([[2000.0, 1000, 2000, 1000]], dtype=torch.float64)  # net angular momentum along +z
    _, t = wrench("rotor_inertia", state(w=(1.0, 0, 0)), om=om)
    h = fx.ROTOR_INERTIA * 2000.0
    assert torch.allclose(t[0], torch.tensor([0.0, h, 0.0], dtype=torch.float64))  # -w x h


def test_random_effects_are_band_limited_with_their_stated_size_and_replay_from_the_seed():
    """One long realisation: each channel's std is the stated one (the sampling error of a 1 Hz
    process over 2000 s is about 2 %, of a 0.4 Hz one about 3 %), almost no power above five
    times each channel's corner frequency (a second-order low-pass at 1 Hz leaves about 4 % of
    its power above 2 Hz: the roll torque's lower corner is checked), the same for the same key
    and a prefix of a longer one, another for another flight."""
    world = fx.World({"turbulence": 1.0, "unsteady_thrust": 1.0})
    d = world.disturbance([0, 3, 1], 2000.0)[:, :10]  # the gusts' channels after them stay zero
    stated = np.array([*fx.TURBULENCE_FORCE, *fx.TURBULENCE_TORQUE, *[fx.UNSTEADY_THRUST] * 4])
    assert np.allclose(d.std(axis=0), stated, rtol=0.08)
    freq = np.fft.rfftfreq(len(d), 1 / fx.REALISATION_RATE)
    for channel, band in ((0, fx.TURBULENCE_BAND), (3, fx.TURBULENCE_TORQUE_BAND[0]), (5, fx.TURBULENCE_TORQUE_BAND[2]),
                          (6, fx.UNSTEADY_THRUST_BAND)):
        spectrum = np.abs(np.fft.rfft(d[:, channel] - d[:, channel].mean())) ** 2
        assert spectrum[freq > 5 * band].sum() < 0.01 * spectrum.sum()
    short = world.disturbance([0, 3, 1], 10.0)[:, :10]
    assert np.array_equal(short, d[:len(short)])
    other = world.disturbance([0, 3, 2], 10.0)[:, :10]
    assert (np.abs(other - short).max(axis=0) > 0.5 * stated).all()
    half = fx.World({"turbulence": 0.5}).disturbance([0, 3, 1], 10.0)
    assert half[:, :6] == pytest.approx(0.5 * short[:, :6]) and not half[:, 6:].any()


def test_inertia_offset_is_the_true_body(melons):
    """Noise-free flights: physics_full with the nominal inertia misses the effect; with the
    inertia 15 % (roll, pitch) and 25 % (yaw) larger it predicts the flight as with no effect."""
    f, none = melons["inertia_offset"], melons["none"]
    J = tuple(j * k for j, k in zip(V.inertia, (1.15, 1.15, 1.25)))
    true_body = predictors.predictor("physics_full", vehicle=Vehicle(inertia=J))
    nominal = predictors.predictor("physics_full")
    err = protocol.evaluate(true_body, [f]).simerr["w"]
    assert err < 1.5 * protocol.evaluate(nominal, [none]).simerr["w"]
    assert protocol.evaluate(nominal, [f]).simerr["w"] > 3 * err


def test_telemetry_delay_shifts_recorded_rotor_speeds(melons):
    f = melons["telemetry_delay"]
    true = np.column_stack([f.extra[f"true_m{i}_rads"] for i in range(1, 5)])
    assert np.allclose(f.u[3:], true[:-3])  # 30 ms = 3 samples
    assert not np.allclose(f.u, true)


def test_the_configured_world_is_the_records_defaults():
    # one source for the default world: conf/sim lists every effect at its record's strength
    import yaml
    from pathlib import Path

    conf = yaml.safe_load((Path(__file__).resolve().parents[1] / "conf/sim/default.yaml").read_text())
    assert conf["effects"] == {e.name: e.default for e in fx.RECORDS}
    assert sim.DEFAULT_WORLD == {e.name: e.default for e in fx.RECORDS if e.default}


def test_a_world_is_named_by_the_effects_it_has_on():
    # what an error about a world says: its effects that are on, by name, and their strengths
    assert str(fx.World({"turbulence": 0.5, "com_offset": 2.0, "thrust_lag": 0})) == "com_offset 2, turbulence 0.5"
    assert str(fx.World({"thrust_lag": 0.0})) == str(fx.World({})) == "no effect"


def _lift(c, body, omega, omega_dot):
    return torch.nn.functional.pad(c["lift"].expand(*body.x.shape[:-1], 1), (2, 3))


@pytest.fixture
def toy_lift():
    # a world effect that is no part of the simulator: a body-frame upward force of a tenth of
    # the weight at strength 1
    record = fx.WorldEffect("toy_lift", "a lift of a tenth of the weight", "upward body force 0.1 m g", "nothing",
                            prepare=lambda s, vehicle, dtype: {"lift": s * 0.1 * vehicle.mass * 9.81},
                            wrench=_lift)
    fx.register(record)
    yield record
    fx.unregister(record.name)


def test_a_new_world_effect_is_one_record_and_one_config_line(toy_lift, tmp_path):
    import shutil
    from pathlib import Path

    import yaml

    from nanosysid import config

    conf = tmp_path / "conf"
    shutil.copytree(Path(__file__).resolve().parents[1] / "conf", conf)
    default = conf / "sim/default.yaml"
    default.write_text(default.read_text().replace("effects:\n", "effects:\n  toy_lift: 1.0\n", 1))
    effects = yaml.safe_load(config.compose_text([], conf_dir=conf))["sim"]["effects"]
    assert effects["toy_lift"] == 1.0 and "toy_lift" in sim.EFFECTS

    def hover(t):
        p = np.tile([0.0, 0.0, 1.0], (len(t), 1))
        return p, np.zeros_like(p), np.zeros_like(p)

    cfg = SimConfig.from_mapping({"preroll": 1.0, "initial_offset": 0.0})
    without = {k: v for k, v in effects.items() if k != "toy_lift"}
    flights = simulate([sim.FlightSpec(Reference("hover", 2.0, hover), 1, effects=w, name=f"hover_t_run{i}")
                        for i, w in enumerate((effects, without), 1)], cfg=cfg, noise=False, progress=False)
    thrust = [np.mean(sum(f.extra[f"true_m{i}_rads"] ** 2 for i in range(1, 5))) for f in flights]
    # Newton, level hover: the rotors carry the weight less the lift, 0.9 m g against m g in the
    # same world otherwise (same seed: the same turbulence)
    assert thrust[0] / thrust[1] == pytest.approx(0.9, rel=5e-3)


def test_every_effect_is_visible_to_the_nominal_model(melons):
    """Noise-free: physics_full is near perfect with no effect, and each effect raises its error."""
    full, naive = predictors.predictor("physics_full"), predictors.predictor("naive")
    none = protocol.evaluate(full, [melons["none"]], horizon=50).mae["p"][49]
    assert none < 0.01 * protocol.evaluate(naive, [melons["none"]], horizon=50).mae["p"][49]
    assert set(sim.EFFECTS) <= set(melons)
    for e in sim.EFFECTS:
        err = protocol.evaluate(full, [melons[e]], horizon=50).mae["p"][49]
        assert err > 1.3 * none, f"{e}: {err:.4g} vs {none:.4g} without effects"


# ---- flights, determinism, oracle -----------------------------------------------------------


def test_flight_layout_truth_and_noise():
    # the gyro read with its own std per body axis (roll, pitch, yaw); 0 reads the true rate (the
    # vibration's growth with the rotors' acceleration off: one level throughout)
    cfg = dataclasses.replace(SHORT, noise=NoiseConfig.from_mapping({"gyro": [0.05, 0.2, 0.0], "vibration_ref": 0}))
    f = sim.simulate_flight("square", 2, cfg=cfg, seed=1)
    assert len(f) == 1901 and np.isclose(f.t[-1] - f.t[0], 19.0)
    assert f.name == "square_20250601_run2" and f.trajectory == "square"
    truth = np.column_stack([f.extra[f"true_{c}"] for c in ("x", "y", "z")])
    err = f.y[:, :3] - truth
    assert 1e-4 < err.std() < 2e-3  # measurement noise of about 0.5 mm
    gyro = f.y[:, 10:13] - np.column_stack([f.extra[f"true_{c}"] for c in ("wx", "wy", "wz")])
    assert np.allclose(gyro[:, :2].std(axis=0), [0.05, 0.2], rtol=0.1)  # 1901 samples: about 2 % spread
    assert np.abs(gyro[:, 2]).max() < 1e-9
    assert np.allclose(np.linalg.norm(f.y[:, 6:10], axis=1), 1)
    # the accelerometer measures the specific force: about g along body z in hover
    assert abs(np.median(f.extra["true_az_body"]) - V.gravity) < 0.5


def test_vibration_grows_with_the_rotors_acceleration():
    from nanosysid.sim.simulator import vibration_scale

    t = np.arange(0, 2, 0.01)[:, None]
    # rotors at rest or at a steady speed: the still level
    assert np.allclose(vibration_scale(np.full((200, 4), 1800.0), 0.01, 500.0), 1.0)
    # every rotor speeding up or slowing down at 500 rad/s^2 (signs apart): sqrt(1 + 1) throughout
    ramp = 1800.0 + 500.0 * t * np.array([1, -1, 1, -1])
    assert np.allclose(vibration_scale(ramp, 0.01, 500.0), np.sqrt(2.0))
    # two rotors at 1000 rad/s^2, two steady: a mean |dOmega/dt| of 500
    half = 1800.0 + 1000.0 * t * np.array([1, 0, -1, 0])
    assert np.allclose(vibration_scale(half, 0.01, 500.0), np.sqrt(2.0))
    assert np.allclose(vibration_scale(half, 0.01, 0.0), 1.0)  # 0: one level throughout


def test_the_accelerometer_bias_is_one_per_power_up():
    # no white noise: what the accelerometer reads beyond the true specific force is its bias,
    # constant through a flight, drawn anew for the next
    noise = NoiseConfig.from_mapping({"accel": 0.0, "accel_bias": [0.05, 0.0, 0.1]})
    cfg = dataclasses.replace(SHORT, noise=noise)
    flights = sim.simulate_flights({"chirp": 2}, seed=3, cfg=cfg, progress=False)
    biases = []
    for f in flights:
        err = np.column_stack([f.extra[c] - f.extra[f"true_{c}"] for c in ("ax_body", "ay_body", "az_body")])
        assert np.ptp(err, axis=0).max() < 1e-12
        biases.append(err[0])
    biases = np.array(biases)
    assert np.all(biases[:, 1] == 0) and np.all(biases[:, [0, 2]] != 0)
    assert not np.allclose(biases[0], biases[1])


TINY = SimConfig.from_mapping({
    "preroll": 0.5,
    "trajectories": {"melon": {"duration": 2.5, "circle_time": 1.5, "return_time": 0.5, "ramp_time": 0.15},
                     "chirp": {"duration": 2.5}},
})


def test_same_seed_same_bytes_and_batch_equals_single(tmp_path):
    a = sim.simulate_flights({"melon": 2}, seed=5, cfg=TINY, progress=False)
    b = sim.simulate_flights({"melon": 2}, seed=5, cfg=TINY, progress=False)
    for x, y in zip(a, b):
        write_flight_csv(x, tmp_path / "a.csv")
        write_flight_csv(y, tmp_path / "b.csv")
        assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    single = sim.simulate_flight("melon", 2, seed=5, cfg=TINY)
    assert np.allclose(single.y, a[1].y, atol=1e-12) and np.allclose(single.u, a[1].u, atol=1e-9)
    other = sim.simulate_flight("melon", 2, seed=6, cfg=TINY)
    assert not np.allclose(other.y, single.y)


def test_a_flight_is_the_same_alone_or_in_a_batch_of_other_worlds():
    def push(t, x, omega, omega_dot):
        force = torch.zeros_like(x[..., :3])
        force[..., 1] = 0.01 * torch.sin(t)
        return force, torch.zeros_like(force)

    def lift(t, x, omega, omega_dot, *, k):
        # a family of user effects: flights of partials of it are evaluated in one call
        force = torch.zeros_like(x[..., :3])
        force[..., 2] = k * x[..., 2]
        return force, torch.zeros_like(force)

    specs = [sim.FlightSpec("melon", 1, effects={"rotor_drag": 0.7, "turbulence": 1.0}, seed=3),
             sim.FlightSpec("chirp", 2, effects={}, seed=1, extra_wrench=push),
             sim.FlightSpec("melon", 2, effects={"com_offset": 2.0, "inertia_offset": 1.0}, seed=0),
             sim.FlightSpec("melon", 1, effects={}, seed=2, extra_wrench=functools.partial(lift, k=0.02)),
             sim.FlightSpec("melon", 1, effects={}, seed=2, extra_wrench=functools.partial(lift, k=-0.03))]
    batch = sim.simulate_flights(specs, cfg=TINY, progress=False)
    for spec, b in zip(specs, batch):
        alone = sim.simulate_flights([spec], cfg=TINY, progress=False)[0]
        assert alone.name == b.name
        assert np.array_equal(alone.y, b.y) and np.array_equal(alone.u, b.u)
    # the worlds differ: the same flight in another world is another flight
    assert not np.allclose(batch[0].y, sim.simulate_flight("melon", 1, effects={}, seed=3, cfg=TINY).y)
    assert not np.allclose(batch[3].y, batch[4].y)


def test_the_compiled_step_flies_the_flights_of_the_eager_one():
    """The compiled step computes every effect in every world (at strength 0 where it is off),
    pads the batch with copies and masks the user wrenches per flight; the eager step computes
    only what each batch has. Over 2.5 s of closed-loop flight in four worlds (one with a user
    wrench, one yawing), both agree to rounding: a missing effect, a wrench leaking into
    another flight or a wrong heading would move the flights by millimetres."""
    def push(t, x, omega, omega_dot):
        force = torch.zeros_like(x[..., :3])
        force[..., 0] = 0.01
        return force, torch.zeros_like(force)

    sweep = make_reference("yawsweep", duration=2.5)
    specs = [sim.FlightSpec("melon", 1, effects=None, seed=3),
             sim.FlightSpec("chirp", 1, effects={"rotor_drag": 2.0, "inertia_offset": 1.0}, seed=4, extra_wrench=push),
             sim.FlightSpec(sweep, 1, effects={"rotor_inertia": 1.0}, seed=5),
             sim.FlightSpec("chirp", 2, effects={}, seed=6)]
    compiled = simulate(specs, cfg=TINY, progress=False)
    eager = simulate(specs, cfg=dataclasses.replace(TINY, compile=False), progress=False)
    for c, e in zip(compiled, eager):
        assert np.abs(c.y[:, :3] - e.y[:, :3]).max() < 1e-9, c.name  # m
        assert np.abs(c.u - e.u).max() < 1e-6, c.name  # rad/s
    # the push acts on its own flight only: without it, that flight is another one
    alone = simulate([dataclasses.replace(specs[1], extra_wrench=None)], cfg=TINY, progress=False)[0]
    assert np.abs(alone.y[:, :3] - compiled[1].y[:, :3]).max() > 1e-3


def test_a_complete_nature_gives_the_wrench_of_the_effects_its_worlds_have():
    """Effects at strength 0 add exact zeros: the complete world's wrench (what the compiled
    step computes) is the same bytes as the wrench of only the effects that are on."""
    worlds = [fx.World({"rotor_drag": 0.7, "com_offset": 1.0}), fx.World({}), fx.World({"rotor_inertia": 2.0})]
    g = torch.Generator().manual_seed(0)
    x = torch.randn(3, 13, generator=g, dtype=torch.float64)
    x[:, 6:10] = so3.quat_normalize(x[:, 6:10])
    omega = 2000 + 300 * torch.rand(3, 4, generator=g, dtype=torch.float64)
    omega_dot = 1e4 * torch.randn(3, 4, generator=g, dtype=torch.float64)
    for complete in (False, True):
        f, tq = fx.Nature(worlds, V, complete=complete).wrench(torch.zeros(3, dtype=torch.float64), x, omega, omega_dot)
        if complete:
            assert torch.equal(f, f0) and torch.equal(tq, tq0)
        f0, tq0 = f, tq
    assert torch.count_nonzero(f0[1]) == 0 and torch.count_nonzero(f0[0]) == 3


def test_a_constant_extra_force_moves_the_flight_as_newton_says(melons):
    """No hidden effect, no noise. A constant 10 mN push along body x (0.222 m/s^2 for 45 g)
    adds to the nominal model's position error after h steps the displacement of that
    acceleration, R F / m (h dt)^2 / 2, with R the attitude at the window's start: 1.11 mm at
    h = 10. What the nominal model misses anyway (the rotor speed between its 100 Hz samples)
    is taken out with the same flight flown without the push; the Melon's first second, a
    thrust transient, is left out."""
    force = np.array([0.01, 0.0, 0.0])
    err = {}
    for name in ("pushed", "none"):
        f = melons[name]
        y0, u, y = (a[f.t[:len(f) - 10] >= 1.0] for a in protocol.windows(f, 10))
        err[name] = y[:, -1, :3] - predictors.predictor("physics_full")(y0, u)[:, -1, :3]
        if name == "pushed":
            R = so3.quat_to_rotmat(torch.from_numpy(np.ascontiguousarray(y0[:, 6:10]))).numpy()
    expected = (R @ force) / V.mass * 0.1**2 / 2
    assert np.abs(expected).max() == pytest.approx(1.11e-3, rel=0.01)
    # the attitude turns a little within 0.1 s, and the pushed flight tilts against the push:
    # within 10 % of the push's displacement
    assert np.abs(err["pushed"] - err["none"] - expected).max() < 0.1 * 1.11e-3


def test_the_oracle_knows_turbulence_and_a_users_wrench(melons):
    """Noise-free flights with a time-varying push of the user's and the turbulence: the oracle,
    given the same function and the simulation's seed, predicts them almost exactly; the
    nominal model does not."""
    push = wavering_push
    world = {"turbulence": 1.0}
    f = melons["turbulence_wavering"]
    oracle = protocol.evaluate(sim.oracle(world, seed=4, extra_wrench=push), [f])
    full = protocol.evaluate(predictors.predictor("physics_full"), [f])
    for k in "pvRw":
        assert oracle.simerr[k] < 0.02 * full.simerr[k]
    # another seed is another realisation of the turbulence: the oracle no longer knows it
    wrong = protocol.evaluate(sim.oracle(world, seed=5, extra_wrench=push), [f])
    assert wrong.simerr["w"] > 20 * oracle.simerr["w"]
    with pytest.raises(PredictionError, match="t0"):
        sim.oracle(world, seed=4)(f.y[:2], f.u[None, :5].repeat(2, 0))


def test_the_compiled_oracle_predicts_the_eager_ones_bytes_in_blocks_of_any_size(melons, monkeypatch):
    """The compiled oracle computes every effect (at strength 0 where the world has it off),
    adds the user's wrench outside its graph, cuts the windows into blocks and pads the last
    one with copies (a short one runs eagerly). Against the eager oracle (only the world's effects, the whole batch at
    once) on a world of turbulence, rotor drag and inertia with a user's push: the same bytes,
    across a block's edge and in a padded block; a window alone is the same bytes as in a
    batch. A lost push, a block started at the wrong time or padding leaking into a window
    would move the states by far more than rounding."""
    import importlib

    # (``nanosysid.sim.oracle`` is the function: the module is fetched by its full name)
    # blocks of 64: 109 windows are a block and 45 padded to one; 13 alone run eagerly
    monkeypatch.setattr(importlib.import_module("nanosysid.sim.oracle"), "BLOCK", 64)
    world = {"turbulence": 1.0, "rotor_drag": 1.5, "inertia_offset": 1.0, "rotor_inertia": 1.0}
    f = melons["turbulence_wavering"]
    y0, u, _ = protocol.windows(f, 20)
    starts = np.arange(40, 40 + 109 * 3, 3)
    t0 = f.t[starts] - f.t[0]
    pred = {c: sim.oracle(world, seed=4, extra_wrench=wavering_push, compile=c)(
        y0[starts], u[starts], t0=t0, flight=f.name) for c in (False, True)}
    assert np.array_equal(pred[True], pred[False])
    alone = sim.oracle(world, seed=4, extra_wrench=wavering_push)(y0[starts[3:16]], u[starts[3:16]], t0=t0[3:16],
                                                                   flight=f.name)
    assert np.array_equal(alone, pred[True][3:16])
    # the push is in: without it the states move by millimetres within 0.2 s
    without = sim.oracle(world, seed=4)(y0[starts], u[starts], t0=t0, flight=f.name)
    assert np.abs(without[:, -1, :3] - pred[True][:, -1, :3]).max() > 1e-4

    def steady(t, x, omega, omega_dot):  # one wrench for every window, as the eager sum broadcasts it
        return torch.tensor([0.01, 0.0, 0.0], dtype=torch.float64), torch.zeros(3, dtype=torch.float64)

    pred = [sim.oracle(world, seed=4, extra_wrench=steady, compile=c)(y0[starts], u[starts], t0=t0, flight=f.name)
            for c in (False, True)]
    assert np.array_equal(pred[0], pred[1]) and np.abs(pred[1] - without).max() > 1e-4


def test_oracle_is_the_physical_limit(melons):
    world = {"rotor_drag": 1.0, "com_offset": 1.0, "motor_asymmetry": 1.0}
    f = melons["drag_com_asymmetry"]
    oracle = protocol.evaluate(sim.oracle(world), [f])
    phys = protocol.evaluate(predictors.predictor("physics"), [f])
    full = protocol.evaluate(predictors.predictor("physics_full"), [f])
    for k in "pvRw":
        assert oracle.simerr[k] < 0.2 * min(phys.simerr[k], full.simerr[k])
    assert predictors.predictor("oracle", effects=world)(f.y[:2], f.u[None, :5].repeat(2, 0)).shape == (2, 5, 13)


def test_a_held_oracle_keeps_the_angular_velocity_and_turns_at_that_rate():
    """Held, the oracle's angular velocity stays the window's first and the attitude turns at that
    constant body rate: q(t) = q0 ⊗ (axis sin(|w| t / 2), cos(|w| t / 2)). Integrated, the
    gyroscopic torque w x J w of an unequal inertia moves it."""
    w = torch.tensor([1.0, -0.5, 2.0], dtype=torch.float64)
    q0 = so3.quat_normalize(torch.tensor([0.1, -0.2, 0.3, 0.9], dtype=torch.float64))
    y0 = torch.cat((torch.zeros(3), torch.tensor([0.3, -0.2, 0.1]), q0, w)).to(torch.float64)[None]
    hover = math.sqrt(V.mass * V.gravity / (4 * V.k_f))
    u = np.full((1, 20, 4), hover)
    held = sim.oracle({}, vehicle=V, rotor_delay=0.0, held=True)(y0.numpy(), u)
    free = sim.oracle({}, vehicle=V, rotor_delay=0.0)(y0.numpy(), u)
    assert np.array_equal(held[0, :, 10:], np.broadcast_to(w.numpy(), (20, 3)))
    assert np.abs(free[0, -1, 10:] - w.numpy()).max() > 1e-3
    t = 0.01 * torch.arange(1, 21, dtype=torch.float64)[:, None]
    n = torch.linalg.norm(w)
    turn = torch.cat((torch.sin(n * t / 2) * w / n, torch.cos(n * t / 2)), -1)
    expected = so3.quat_mul(q0.expand(20, 4), turn)
    assert np.abs(held[0, :, 6:10] - expected.numpy()).max() < 1e-8


def test_gusts_are_steps_of_their_stated_size_and_replay_from_the_seed():
    """Gusts hold a level and step to the next: after each step's 0.1 s rise the realisation is
    flat, so with steps every 2 s on average most samples barely move (the smooth turbulence's
    almost never do); each channel's std is the stated one (about 1000 levels in 2000 s: a 3 %
    sampling error, the rise rounding the steps a little); the same key gives the same steps, a
    longer flight's beginning with a shorter one's, another key others."""
    world = fx.World({"gusts": 1.0})
    cols = slice(10, 16)  # after the turbulence's six channels and the four rotors' fluctuations
    d = world.disturbance([0, 3, 1], 2000.0)[:, cols]
    stated = np.array([*fx.GUST_FORCE, *fx.GUST_TORQUE])
    on = stated > 0
    assert np.allclose(d[:, on].std(axis=0), stated[on], rtol=0.1) and not d[:, ~on].any()
    step = np.abs(np.diff(d[:, 0])) / stated[0]
    assert (step < 1e-3).mean() > 0.5
    smooth = fx.World({"turbulence": 1.0}).disturbance([0, 3, 1], 2000.0)[:, 0]
    assert (np.abs(np.diff(smooth)) / smooth.std() < 1e-3).mean() < 0.05
    short = world.disturbance([0, 3, 1], 10.0)[:, cols]
    assert np.array_equal(short, d[:len(short)])
    other = world.disturbance([0, 3, 2], 10.0)[:, cols]
    assert not np.allclose(other[:, on], short[:, on])


def test_a_slow_lag_of_the_wrench_follows_the_turning_speeds_squares_and_moves_the_body():
    # half the rotors' wrench through the 0.3 s lag: the squares the wrench follows are half the
    # turning speeds' squares and half those through a first-order system (scipy's, from hover at
    # rest), the rotors turn within their limits, and the body accelerates as that wrench says
    from scipy import signal

    cfg = dataclasses.replace(SHORT, compile=False)
    raw = simulate_raw([sim.FlightSpec("melon", 1, effects={"thrust_lag": 2.0})], cfg=cfg, progress=False)
    turning, wrench_speeds = raw.turning(0), raw.omega[0]
    assert not np.allclose(turning, wrench_speeds)
    assert cfg.omega_min - 1e-6 <= turning.min() and turning.max() <= cfg.omega_max + 1e-6
    first_order = signal.StateSpace([[-1 / fx.SLOW_ACTUATION_TIME]], [[1 / fx.SLOW_ACTUATION_TIME]], [[1.0]], [[0.0]])
    lagged = np.column_stack([signal.lsim(first_order, turning[:, k] ** 2, raw.t - raw.t[0], X0=[V.hover_speed ** 2])[1]
                              for k in range(4)])
    expected = 0.5 * turning ** 2 + 0.5 * lagged
    assert np.abs(wrench_speeds ** 2 - expected).max() < 5e-3 * V.hover_speed ** 2  # 0.86 from the turning ones
    # v' = R f / m + g, by finite differences of the recorded velocity
    dt = raw.t[1] - raw.t[0]
    x = torch.from_numpy(raw.x[0])
    accel = so3.quat_rotate(x[:-1, 6:10], torch.from_numpy(raw.wrench[0, :-1, :3])).numpy() / V.mass
    accel[:, 2] -= 9.81
    fd = np.diff(raw.x[0, :, 3:6], axis=0) / dt
    # (0.5-1.1 m/s^2 off had the body moved with the turning speeds' thrust)
    assert (np.abs(fd - accel).mean(axis=0) < 0.1).all(), np.abs(fd - accel).mean(axis=0)
