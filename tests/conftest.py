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


# the longest files first, longest to shortest (summed seconds in `make test` on two cores: about
# 400-450, then 75-90 each for the next four, 35-65 for the four after): `make test`'s workers
# take a file each at a time in this order, so the DVC tests start at once, and the files left
# for the end, when one worker may wait for the other, are the short ones
FIRST = ("test_dvc.py", "test_pipeline.py", "test_discover.py", "test_fault_repro.py", "test_learned.py",
         "test_launcher.py", "test_identify.py", "test_numerics.py", "test_sim.py")


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
