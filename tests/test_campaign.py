"""The campaign's family counts, on rows made by hand."""

from nanosysid.campaign import summarize_families


def _row(family, **kw):
    row = {"family": family, "named": [], "ambiguous": [], "history_dropped": [], "sources": [], "repeats": [],
           "inertia_z": {"error": 0.0, "claimed": False}}
    row.update(kw)
    return row


def test_a_failed_world_counts_in_its_family_a_diverged_one_keeps_its_verdicts_a_repeating_residual_is_not_of_time():
    rows = [
        _row("state", repeats=["tau_x"]),  # left unnamed: it repeats with the reference
        _row("state", sources=["time"], inertia_z={"error": 0.2, "claimed": False}),
        {"family": "state", "error": "the prediction is nan"},
        _row("turbulence", sources=["time", "time"], history_dropped=["slow_actuation"]),
        # its augmented model diverged on the test flight: its verdicts still count
        _row("thrust_lag", named=["slow_actuation"], diverged="the prediction is nan"),
    ]
    got = summarize_families(rows)
    assert (got["state"]["worlds"], got["state"]["failed"]) == (2, 1)
    assert (got["state"]["stateless"], got["state"]["of_time"], got["state"]["repeats"]) == (1, 1, 1)
    assert got["state"]["inertia_z_within"] == 1
    assert (got["turbulence"]["of_time"], got["turbulence"]["slow_actuation_dropped"]) == (1, 1)
    assert got["thrust_lag"]["worlds"] == got["thrust_lag"]["slow_actuation_named"] == got["thrust_lag"]["diverged"] == 1
    assert got["state"]["diverged"] == 0


def test_a_short_random_flies_the_logged_waypoints_at_their_own_pace():
    # 50 waypoints over 60 s, one every 60/49 = 1.224 s: 20 s hold 16.3 intervals, so the first 17
    # waypoints, 1.25 s apart; drawn waypoints (no list) keep their count of about one a second
    from nanosysid.campaign import short_flights_config
    from nanosysid.sim.simulator import SimConfig

    points = [[0.1 * i, 0.0, 1.5] for i in range(50)]
    others = {"melon": {}, "yawsweep": {}}
    base = SimConfig(trajectories={"random": {"duration": 60.0, "points": points}, **others})
    short = short_flights_config(20.0, base, calibration=10.0).trajectories["random"]
    assert short["duration"] == 20.0 and short["points"] == points[:17]
    drawn = SimConfig(trajectories={"random": {"duration": 60.0, "points": None}, **others})
    assert short_flights_config(20.0, drawn, calibration=10.0).trajectories["random"]["n_points"] == 18
