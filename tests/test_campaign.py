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
