"""k_F / k_M identification: known answers on flights of the nominal dynamics."""

import dataclasses
import re

import numpy as np
import pandas as pd
import pytest
from scipy.signal import lfilter

from nanosysid import identify, predictors, synthetic
from nanosysid.dataio import Flight
from nanosysid.errors import DataError
from nanosysid.vehicle import Vehicle


def test_recovers_the_coefficients_the_flights_were_made_with(tmp_path):
    truth = dataclasses.replace(Vehicle(), k_f=4.1e-8, k_m=9.0e-11)
    names = [f"chirp_x_run{k}" for k in range(1, 4)]
    flights = synthetic.synthetic_flights(names, 1500, vehicle=truth, noise=0.0, seed=2)
    thrust = identify.fit_thrust(flights, truth)
    yaw = identify.fit_yaw_moment(flights, truth)
    assert abs(thrust.coef / truth.k_f - 1) < 1e-6 and thrust.r2 > 0.999999
    assert abs(yaw.coef / truth.k_m - 1) < 0.01 and yaw.r2 > 0.99 and abs(yaw.intercept) < 1e-7
    assert thrust.stderr < 1e-3 * thrust.coef and yaw.stderr < 0.01 * yaw.coef


def test_yaw_offset_goes_to_the_intercept_not_to_k_m():
    truth = Vehicle()
    flights = synthetic.synthetic_flights(["chirp_x_run1", "chirp_x_run2"], 1500, noise=0.0, seed=3)
    for f in flights:
        # a constant yaw torque on top: the gyro-reconstructed torque shifts by it
        f.y[:, 12] += 2e-5 / truth.inertia[2] * (f.t - f.t[0])
    yaw = identify.fit_yaw_moment(flights, truth)
    assert abs(yaw.coef / truth.k_m - 1) < 0.02 and np.isclose(yaw.intercept, 2e-5, rtol=0.02)


def test_physics_models_use_the_identified_coefficients(tmp_path):
    path = tmp_path / "params.json"
    fit = identify.Fit(coef=4.0e-8, stderr=1e-10, r2=0.99, intercept=0.0, n=10)
    identify.write_identified(path, fit, dataclasses.replace(fit, coef=8.0e-11), [])
    v = identify.identified_vehicle(Vehicle(), path)
    assert v.k_f == 4.0e-8 and v.k_m == 8.0e-11 and v.mass == Vehicle().mass
    step = predictors.predictor("physics_full", identified=str(path)).step
    assert step.vehicle.k_f == 4.0e-8


@pytest.mark.parametrize("content, problem", [
    (None, "no identified parameters; the identify stage writes it"),
    ("{not json", "not valid JSON"),
    ('{"k_f": 4e-8, "k_m": 8e-11}', "field 'format'"),
    ('{"format": "nanosysid-identified-1", "k_f": "big", "k_m": 8e-11}', "field 'k_f' is 'big'"),
    ('{"format": "nanosysid-identified-1", "k_f": 4e-8, "k_m": -1}', "field 'k_m' is -1"),
])
def test_bad_identified_parameters_are_one_clear_error(tmp_path, content, problem):
    path = tmp_path / "params.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(DataError, match=re.escape(problem)) as e:
        identify.identified_vehicle(Vehicle(), path)
    assert str(path) in str(e.value)


def test_identify_stage_on_an_empty_training_folder(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from nanosysid.dataio import write_flight_csv

    root = Path(__file__).resolve().parents[1]
    (tmp_path / "split" / "train").mkdir(parents=True)
    (flight,) = synthetic.synthetic_flights(["melon_20250601_run1"], 300, noise=0.0, seed=1)
    write_flight_csv(flight, tmp_path / "split" / "test" / "melon_20250601_run1.csv")
    out = tmp_path / "identified"
    r = subprocess.run([sys.executable, "-m", "stages.identify", f"paths.split={tmp_path / 'split'}",
                        f"identify.out_dir={out}"], cwd=root, capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == f"error: {tmp_path / 'split' / 'train'}: no flight CSV files to fit k_F and k_M on"
    assert not out.exists()


def test_flight_jackknife_interval_covers_the_truth_where_the_white_residual_one_does_not():
    # Flights as independent repeats: each flight's accelerometer error is slow (an AR(1) with
    # a 2 s correlation time, like a drifting bias), so the samples of one flight are not
    # independent. The delete-one-flight jackknife with Student's t (11 degrees of freedom)
    # must cover the truth about 95 % of the time; the white-residual error, which counts
    # every sample as independent, covers far less.
    rng = np.random.default_rng(5)
    truth, vehicle = 3.72e-8, Vehicle()
    T, a = 400, np.exp(-0.01 / 2.0)
    jack = white = 0
    reps = 400
    for _ in range(reps):
        flights = []
        for k in range(12):
            u = 1800 + 300 * np.sin(np.linspace(0, 6, T)[:, None] + rng.uniform(0, 6, 4)) + rng.normal(0, 20, (T, 4))
            drive = rng.normal(size=T) * np.sqrt(1 - a * a)
            drive[0] = rng.normal()  # started in its stationary distribution
            e = lfilter([1.0], [1.0, -a], drive)
            az = truth * (u**2).sum(1) / vehicle.mass + 0.3 * e
            flights.append(synthetic_flight(f"chirp_x_run{k + 1}", u, az))
        fit = identify.fit_thrust(flights, vehicle)
        lo, hi = fit.ci95
        jack += lo <= truth <= hi
        white += abs(fit.coef - truth) <= 1.96 * fit.stderr
    assert 0.92 <= jack / reps <= 0.98
    assert white / reps < 0.6


def synthetic_flight(name, u, az):
    T = len(u)
    y = np.zeros((T, 13))
    y[:, 9] = 1.0
    return Flight(name=name, t=np.arange(T) * 0.01, u=u, y=y, extra={"az_body": az})


def test_k_m_by_instruments_holds_in_closed_loop_where_least_squares_does_not():
    # Calibration flights (hover, yaw setpoint multisine) in the default world less the
    # telemetry delay, each with its own turbulence and rotor-thrust fluctuation: the yaw loop
    # cancels those torques through the rotor-speed difference. Least squares on the
    # closed-loop flights falls well short of nature's k_M; instrumental variables with the
    # setpoint as instrument recover it, and the block-jackknife interval covers it in most.
    from nanosysid import sim
    from nanosysid.sim.simulator import SimConfig

    world = {k: v for k, v in sim.DEFAULT_WORLD.items() if k != "telemetry_delay"}
    cfg = SimConfig.from_mapping({"preroll": 1.0, "postroll": 0.0,
                                  "trajectories": {"yawsweep": {"duration": 30.0, "fade": 2.0}}})
    flights = sim.simulate([sim.FlightSpec("yawsweep", run=k, effects=world, seed=11) for k in range(1, 13)],
                           cfg=cfg, progress=False)
    truth = Vehicle().k_m
    covered, errors = 0, []
    for f in flights:
        iv = identify.fit_yaw_moment_iv([f], Vehicle(), blocks=6)
        ls = identify.fit_yaw_moment([f], Vehicle())
        assert ls.coef < 0.8 * truth  # the closed loop's bias
        errors.append(iv.coef / truth - 1)
        covered += iv.ci95[0] <= truth <= iv.ci95[1]
    # 30 s flights are short: each estimate is within about 10 %, their mean within a few per cent
    assert abs(np.mean(errors)) < 0.08 and np.median(np.abs(errors)) < 0.15
    assert covered >= 10  # of 12: a 95 % interval misses two or more about one time in eight


# Two worlds of the campaign flown in one batch (the yaw calibration flight cut to 30 s, half the
# campaign's: the longest flight sets the batch's time): telemetry 60 ms late on a quiet rig, and
# 30 ms late on a rig whose rotors' thrust fluctuates 2.2 times the default's
CAMPAIGN_WORLDS = ({"telemetry_delay": 2.0, "rotor_drag": 1.0}, {"telemetry_delay": 1.0, "unsteady_thrust": 2.2})


@pytest.fixture(scope="module")
def campaign_flights():
    from nanosysid import campaign

    worlds = [campaign.HiddenWorld(i, effects, seed=s) for i, (effects, s) in enumerate(zip(CAMPAIGN_WORLDS, (5, 9)))]
    setup = campaign.Setup(sim=campaign.short_flights_config(calibration=30.0))
    flights = campaign.simulate(worlds, setup)
    return worlds, setup, [flights[w.index][0] for w in worlds]


def test_the_campaign_judges_a_worlds_motor_lag_k_f_and_k_m(campaign_flights):
    # the lag with the flights' setpoints as instruments, then k_F and k_M with the rotor speeds
    # moved back by it
    from nanosysid import campaign

    (world, _), setup, (flights, _) = campaign_flights
    assert sorted(f.trajectory for f in flights) == ["chirp", "melon", "random", "square", "yawsweep"]
    ident = campaign.identification(world, flights, setup=setup)
    assert ident["lag_true"] == pytest.approx(0.060) and abs(ident["lag_error"]) < 0.003
    assert abs(ident["k_f_error"]) < 0.01 and ident["k_m_identifiable"] and abs(ident["k_m_error"]) < 0.15
    summary = campaign.summarize_identification([ident])
    assert summary["lag_within"] == 1.0 and summary["worlds"] == 1


def test_a_rig_whose_loop_fights_strong_thrust_disturbances_gets_its_lag_from_the_setpoints(campaign_flights):
    # The loop answers the strong thrust fluctuations with fast rotor-speed changes: at most the
    # Melon's jump from the takeoff height stands out lag_threshold times above them, too few for
    # an interval, and early by several ms. Relaxed until they give an interval, the transients take
    # in some of the loop's answers and stay more than 5 ms early. The setpoints do not answer
    # the disturbances: as instruments they put the lag nearer the world's than the transients
    # do, within 4 ms (3.2 ms at the rig's noise), inside the interval.
    from nanosysid import campaign
    from nanosysid.preprocess.lag import motor_lag_estimate, motor_lag_evidence

    (_, world), setup, (_, flights) = campaign_flights
    cfg = setup.sync
    evidence = [motor_lag_evidence(f.name, pd.DataFrame({"t_src": f.t, "az": f.extra["az_body"]}),
                                   pd.DataFrame({"t_src": f.t, **{f"m{i + 1}": f.u[:, i] for i in range(4)}}), cfg)
                for f in flights]
    fixed = motor_lag_estimate(evidence, cfg, threshold=cfg.lag_threshold * np.median([e.background for e in evidence]))
    assert fixed.events <= 1 and fixed.interval == (None, None) and abs(fixed.value - 0.030) > 0.005
    relaxed = motor_lag_estimate(evidence, cfg)
    assert "threshold relaxed" in relaxed.method and relaxed.units >= 2 and relaxed.value < 0.030 - 0.005
    ident = campaign.identification(world, flights, setup=setup)
    assert ident["lag_true"] == pytest.approx(0.030)
    assert ident["lag_covered"] and abs(ident["lag_error"]) < min(0.004, abs(relaxed.value - 0.030))
    instrumented = motor_lag_estimate([campaign.lag_evidence(f, setup) for f in flights], cfg)
    assert instrumented.method == "the setpoints as instruments" and instrumented.value == ident["lag"]


def test_k_m_interval_over_the_yaw_inertias_range_covers_a_body_heavier_in_yaw():
    # A yaw calibration flight of a body whose yaw inertia is 50 % above the vehicle's (roll
    # and pitch 30 %): the gyro's torque read with the vehicle's J_z puts k_M a third low, and
    # the interval for that J_z misses nature's; read with the body's own inertia, the same fit
    # gives nature's k_M (the yaw coefficients scale with J_z, so k_M is the ratio's); the
    # interval over the sources' J_z range (up to 1.82 times the vehicle's) holds it.
    from nanosysid import sim
    from nanosysid.sim.simulator import SimConfig

    vehicle = Vehicle()
    jz = vehicle.inertia[2]
    world = {"inertia_offset": 2.0}
    body = sim.World(world).inertia(vehicle)
    assert body[2] == pytest.approx(1.5 * jz)
    cfg = SimConfig.from_mapping({"preroll": 1.0, "postroll": 0.0,
                                  "trajectories": {"yawsweep": {"duration": 30.0, "fade": 2.0}}})
    [f] = sim.simulate([sim.FlightSpec("yawsweep", run=1, effects=world, seed=3)], cfg=cfg, progress=False)
    fit = identify.fit_yaw_moment_iv([f], vehicle, blocks=6)
    assert fit.coef / vehicle.k_m - 1 == pytest.approx(1 / 1.5 - 1, abs=0.08)
    assert not fit.ci95[0] <= vehicle.k_m <= fit.ci95[1]
    own = identify.fit_yaw_moment_iv([f], dataclasses.replace(vehicle, inertia=body), blocks=6)
    assert own.coef == pytest.approx(vehicle.k_m, rel=0.08)
    wide = identify.with_inertia_range(fit, jz, (jz, 5.9e-5))
    assert wide.coef == fit.coef and wide.ci95_inertia[0] == fit.ci95[0]
    assert wide.ci95_inertia[0] <= vehicle.k_m <= wide.ci95_inertia[1]
    with pytest.raises(DataError, match="identify.inertia_z_range.*does not hold the vehicle's yaw inertia"):
        identify.with_inertia_range(fit, jz, (4e-5, 5.9e-5))
