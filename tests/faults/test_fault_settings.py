"""Settings of the wrong kind, out of range or not the data's are refused where the config is
read, in one line naming the setting and what it must be."""

from __future__ import annotations


import pytest

from nanosysid import config
from nanosysid.errors import ConfigError


CASES = [
    ("seed=abc", "seed must be a whole number >= 0"),
    ("seed=-1", "seed must be a whole number >= 0"),
    ("seed=1.5", "seed must be a whole number >= 0"),
    ("discover.folds=0", "discover.folds must be a whole number >= 2"),
    ("discover.folds=1", "discover.folds must be a whole number >= 2"),
    ("discover.folds=2.5", "discover.folds must be a whole number >= 2"),
    ("discover.block=0", "discover.block must be a positive number"),
    ("discover.block=-2", "discover.block must be a positive number"),
    ("discover.block=.inf", "discover.block must be a positive number"),
    ("models.physics.dt=0.02", "models.physics.dt = 0.02 s; the flights are sampled every 0.01 s"),
    ("models.physics_full.dt=0.005", "models.physics_full.dt = 0.005 s"),
    ("discover.oracle.dt=0.02", "discover.oracle.dt = 0.02 s"),
    ("recording.sync.rate=50", "recording.sync.rate = 50 Hz; the benchmark's flights are at 100 Hz"),
    ("recording.filter.rate=200", "recording.filter.rate = 200 Hz"),
    ("eval.horizon=0", "eval.horizon must be a positive whole number"),
    ("eval.horizon=ten", "eval.horizon must be a positive whole number"),
    ("models.lstm.train.optimizer.lr=-1", "models.lstm.train.optimizer.lr must be a positive number"),
    ("models.lstm.train.epochs=0", "models.lstm.train.epochs must be a positive whole number"),
    ("vehicle.mass=heavy", "vehicle.mass must be a positive number"),
    ("vehicle.k_f=0", "vehicle.k_f must be a positive number"),
    ("identify.iv_blocks=0", "identify.iv_blocks must be a positive whole number"),
    ("campaign.worlds=0", "campaign.worlds must be a positive whole number"),
    ("sim.runs.melon=-1", "sim.runs.melon must be a whole number >= 0"),
    ("recording.filter.position=60", "recording.filter.position = 60 Hz is at or above the Nyquist"),
]

CLASS = "unchecked setting"


@pytest.mark.parametrize("override,words", CASES, ids=[c[0] for c in CASES])
def test_a_bad_setting_is_one_error_naming_it(params, override, words):
    with pytest.raises(ConfigError) as e:
        config.load_params([override], path=params)
    assert words in str(e.value), str(e.value)
    assert "\n" not in str(e.value)


def test_the_default_settings_pass(params):
    config.load_params([], path=params)
