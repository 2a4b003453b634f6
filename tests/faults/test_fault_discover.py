"""Discovery says it cannot judge, and why, where its tests could find nothing whatever the
world holds (flights that barely move, too few blocks for any test to reach its level), instead
of reporting "no disagreement above the noise floor"."""

from __future__ import annotations

import pytest

from nanosysid import discover, sim
from nanosysid.errors import ConfigError, DataError
from nanosysid.sim.simulator import SimConfig

CLASS = "wrong result written"

# a world with every catalogue drag and the propellers' gyro: there is something to find
EFFECTS = {"rotor_drag": 1.0, "body_drag": 1.0, "rotor_inertia": 1.0}


def flights(trajectories, runs=(1, 2), effects=EFFECTS):
    cfg = SimConfig.from_mapping({"trajectories": trajectories})
    specs = [sim.FlightSpec(trajectory=tr, run=r, effects=effects, seed=1) for tr in trajectories for r in runs]
    return sim.simulate_flights(specs, cfg=cfg, progress=False)


@pytest.fixture(scope="module")
def hover():
    """Two 25 s flights holding one point (a chirp of zero amplitude)."""
    return flights({"chirp": {"amplitude": 0.0, "duration": 25.0}})


@pytest.fixture(scope="module")
def short():
    """Two 8 s chirps: 8 blocks of 2 s."""
    return flights({"chirp": {"duration": 8.0}})


def test_hover_only_flights_cannot_be_judged(hover):
    with pytest.raises(DataError, match=r"discover cannot judge: the training flights barely move \(RMS distance from their mean position 0\.0\d+ m"):
        discover.run(hover, hover[:1], analysis=False)


def test_a_hover_in_turbulent_air_cannot_be_judged_either():
    """In the default world's air the controller's answers to the turbulence turn the body at
    about 0.2 rad/s RMS while it holds its point within 2 cm: nothing of the library is excited."""
    air = flights({"chirp": {"amplitude": 0.0001, "duration": 12.0}}, effects=None)
    with pytest.raises(DataError, match=r"discover cannot judge: the training flights barely move \(RMS distance from "
                                        r"their mean position 0\.0[0-4]\d m, RMS angular rate 0\.[1-3]\d+ rad/s"):
        discover.run(air, air[:1], analysis=False, block=1.0)


# the library's 17 entries: 2^11 = 2048 >= 17 / 0.01, and 2^15 >= 17 / 0.001 > 2^14 = 16384
@pytest.mark.parametrize("alpha,blocks", [(0.01, 11), (0.001, 15)])
def test_too_few_blocks_for_any_test_cannot_be_judged(short, alpha, blocks):
    with pytest.raises(DataError, match=rf"discover cannot judge: .* no finding is possible below {blocks} blocks"):
        discover.run(short, short[:1], alpha=alpha, analysis=False)


@pytest.mark.parametrize("setting,value,words", [
    ("folds", 1, "discover.folds: 1; it must be an integer of at least 2"),
    ("block", 0.0, "discover.block: 0.0; it must be a positive number of seconds"),
    ("alpha", 1.5, "discover.alpha: 1.5; it must be between 0 and 1"),
    ("share", -0.1, "discover.share: -0.1; it must be between 0 and 1"),
    ("window", 4, "discover.window: 4; it must be an odd integer above the order 3"),
])
def test_a_setting_that_makes_every_test_meaningless_is_refused(short, setting, value, words):
    with pytest.raises(ConfigError) as e:
        discover.run(short, short[:1], analysis=False, **{setting: value})
    assert words in str(e.value), str(e.value)
