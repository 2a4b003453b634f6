"""The launcher: the same results in the tasks' order wherever they run, the SLURM executor
built from conf/launcher/slurm.yaml (submitit's debug executor stands in for the cluster), and
the campaign stage's summary the same with one or two local workers."""

import json
import math
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from nanosysid import config
from nanosysid.errors import ConfigError
from nanosysid.launcher import Launcher, even_parts, map_tasks, slurm_executor

ROOT = Path(__file__).resolve().parents[1]
SLURM = OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "launcher" / "slurm.yaml"))


def hypot(a, b):
    import numpy  # noqa: F401 (loads its BLAS)
    import torch
    from threadpoolctl import threadpool_info

    # the task sees the launcher's thread count, torch's and numpy's BLAS's, whatever the parent
    # process uses (the pinned environment gives every library two)
    blas = {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}
    assert blas, "no BLAS found loaded"
    return math.hypot(a, b), torch.get_num_threads(), blas


TASKS = [(3.0, 4.0), (5.0, 12.0), (8.0, 15.0)]


def test_local_workers_return_results_in_the_tasks_order():
    for workers in (1, 2):
        out = map_tasks(hypot, TASKS, Launcher(workers=workers))
        assert out == [(5.0, 1, {1}), (13.0, 1, {1}), (17.0, 1, {1})]
    assert map_tasks(hypot, TASKS[:1], Launcher(workers=1, threads=3)) == [(5.0, 3, {3})]


@pytest.mark.parametrize("n, size, slots, sizes", [
    (200, 15, 2, [15] * 4 + [14] * 10),  # 14 parts of 15 but the last of 5 would leave one worker 10 worlds more
    (60, 15, 2, [15] * 4),               # already even: the same parts as fixed 15s
    (61, 15, 2, [11] * 1 + [10] * 5),    # 5 parts of 15 -> 6 (a multiple of 2): 61 = 11 + 5 x 10
    (5, 15, 2, [3, 2]),                  # one part would leave a worker idle
    (1, 15, 4, [1]),                     # never an empty part
    (0, 15, 2, []),
    (9, 4, 1, [3, 3, 3]),                # one slot: the fewest parts of at most 4
])
def test_even_parts_cut_the_worlds_evenly_over_the_slots(n, size, slots, sizes):
    parts = even_parts(n, size, slots)
    assert [len(p) for p in parts] == sizes
    assert [i for p in parts for i in p] == list(range(n))  # every world once, in order


def test_slurm_executor_carries_the_configs_partition_time_and_memory(tmp_path, monkeypatch):
    from submitit.slurm.slurm import SlurmExecutor

    monkeypatch.setattr(SlurmExecutor, "affinity", staticmethod(lambda: 1))  # as if srun were there
    monkeypatch.setattr("nanosysid.launcher.shutil.which", lambda name: f"/usr/bin/{name}")
    spec = Launcher.from_mapping({**SLURM, "partition": "gpu", "time_min": 90, "mem_gb": 16, "workers": 8,
                                  "folder": str(tmp_path)})
    ex = slurm_executor(spec)
    p = ex._executor.parameters  # what sbatch would be given
    assert p["partition"] == "gpu" and p["time"] == 90 and p["mem"] == "16GB" and p["array_parallelism"] == 8


def test_slurm_path_runs_tasks_through_submitit(tmp_path):
    spec = Launcher.from_mapping({**SLURM, "cluster": "debug", "folder": str(tmp_path / "jobs")})
    assert map_tasks(hypot, TASKS, spec) == [(5.0, 1, {1}), (13.0, 1, {1}), (17.0, 1, {1})]
    assert any((tmp_path / "jobs").iterdir())  # submitit's job folders, on the "shared" folder


@pytest.mark.parametrize("block, message", [
    ({"kind": "cloud"}, "launcher.kind: 'cloud' is not one of local, slurm"),
    ({"workers": 0}, "launcher.workers: 0 is not a positive whole number"),
    ({"partitoin": "gpu"}, "launcher: unknown key(s) partitoin"),
])
def test_bad_launcher_config_is_one_clear_error(block, message):
    with pytest.raises(ConfigError) as e:
        Launcher.from_mapping(block)
    assert message in str(e.value)


def test_a_stage_command_line_chooses_the_launcher_group(tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    params = tmp_path / "params.yaml"
    config.compose([], out=params)
    cfg = config.load_params(["launcher=slurm", "launcher.partition=gpu"], path=params)
    assert cfg.launcher.kind == "slurm" and cfg.launcher.partition == "gpu" and cfg.launcher.time_min == SLURM["time_min"]
    with pytest.raises(ConfigError, match="no option 'cluster' in conf/launcher/ \\(known: local, slurm\\)"):
        config.load_params(["launcher=cluster"], path=params)


@pytest.mark.parametrize("duration", [6.0, 15.0])
def test_a_short_campaign_flies_a_shorter_square_as_hard_as_the_full_one(duration):
    # the square sets a campaign batch's length: cut to the campaign's duration, its moves keep
    # the full square's peak acceleration (the 1 m edges in 1 s moves: about 7.5 m/s^2)
    import numpy as np

    from nanosysid.campaign import short_flights_config
    from nanosysid.sim.trajectories import make_reference

    def peak(options):
        ref = make_reference("square", **options)
        _, _, a = ref.pva(np.arange(0.0, ref.duration, 1e-3))
        return ref.duration, np.abs(a).max()

    full = short_flights_config(20.0).trajectories["square"]
    assert peak(full)[0] == pytest.approx(19.0) and 7.0 < peak(full)[1] < 8.0
    length, acc = peak(short_flights_config(duration).trajectories["square"])
    assert duration - 0.01 <= length <= duration + 1e-9 and acc == pytest.approx(peak(full)[1], rel=1e-3)


@pytest.mark.slow
def test_campaign_gives_the_same_bytes_with_one_or_two_workers(tmp_path, monkeypatch):
    from stages import campaign
    from stages.common import run_stage

    monkeypatch.chdir(ROOT)
    params = tmp_path / "params.yaml"
    config.compose([], out=params)
    for workers in (1, 2):
        # a drawn world and a family's; one worker: both in one batch; two workers: a batch each
        # (the tasks are even)
        argv = ["--params", str(params), "campaign.worlds=1", "campaign.chunk=2", "campaign.duration=10.0",
                "campaign.families.thrust_lag=1", "campaign.families.turbulence=0", "campaign.families.state=0",
                "campaign.families.gusts=0", "campaign.families.residual_delay=0", "sim.flight.trajectories.yawsweep.duration=6.0",
                "sim.flight.compile=false", "launcher=local", f"launcher.workers={workers}",
                f"campaign.out_dir={tmp_path / str(workers)}"]
        assert run_stage(campaign.main, description="", argv=argv) == 0
    for name in ("summary.json", "worlds.parquet", "summary.md", "families.json"):
        assert (tmp_path / "1" / name).read_bytes() == (tmp_path / "2" / name).read_bytes(), name
    import pandas as pd

    table = pd.read_parquet(tmp_path / "1" / "worlds.parquet")
    assert list(table["world"]) == [0]
    kin = json.loads((tmp_path / "1" / "families.json").read_text())
    assert [(r["world"], r["family"]) for r in kin] == [(1, "thrust_lag")]
