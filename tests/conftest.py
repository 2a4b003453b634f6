import os
from pathlib import Path

from nanosysid import numerics

numerics.pin()  # before numpy and torch are loaded, as every stage does

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from dvcenv import dvc_env  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

# two cores: two threads for a serial run; one for each of `make test`'s workers (pytest-xdist),
# which would otherwise contend for the same two cores
torch.set_num_threads(2 if os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") == "1" else 1)


# the longest files first, longest to shortest (summed seconds in a fresh clone's `make test` on
# two cores: about 320 for the DVC tests, 105 for discovery's, 40-75 each for the next nine, 10-26
# for the nine after): `make test`'s workers take a file each at a time in this order, so the DVC
# tests start at once, and the files left for the end, when one worker may wait for the other, are
# the short ones
FIRST = ("test_dvc.py", "test_discover.py", "test_learned.py", "test_fault_repro.py", "test_launcher.py",
         "test_sim.py", "test_pipeline.py", "test_dependencies.py", "test_identify.py", "test_numerics.py",
         "test_repro.py", "test_fault_signals.py", "test_config.py", "test_consistency.py", "test_recording.py",
         "test_fault_cache.py", "test_fault_bags.py", "test_fault_settings.py", "test_fault_discover.py",
         "test_fault_stage_paths.py")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(FIRST)))  # stable: the rest keep their order


@pytest.fixture
def venv_env():
    """Environment in which `python` and `dvc` are this interpreter's (the venv's)."""
    return dvc_env()


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(scope="session")
def raw():
    """The raw record of one short simulated Melon flight (:mod:`bagtools`)."""
    import bagtools

    return bagtools.simulate_melon()


@pytest.fixture(scope="session")
def bag(raw, tmp_path_factory):
    """That flight recorded as a ROS 2 bag, as the rig records it."""
    import bagtools

    path = tmp_path_factory.mktemp("bags") / "melon_20250601_run1"
    bagtools.record(raw, path)
    return path
