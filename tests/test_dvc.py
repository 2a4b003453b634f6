"""The pipeline as DVC runs it: only what changed reruns, queued experiments share the run cache,
outputs and the run cache travel through a remote."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from test_pipeline import TINY_SIM

ROOT = Path(__file__).resolve().parents[1]


class DvcRepo:
    """A copy of the project as its own git and DVC repository, with its own cache."""

    def __init__(self, root: Path, env: dict):
        self.root, self.env = root, env
        root.mkdir(parents=True)
        for item in ("dvc.yaml", "params.yaml", "conf", "stages", "src", ".dvc", ".dvcignore", ".gitignore"):
            src = ROOT / item
            if src.is_dir():
                shutil.copytree(src, root / item, ignore=shutil.ignore_patterns("__pycache__"))
            else:
                shutil.copy(src, root / item)
        shutil.rmtree(root / ".dvc" / "tmp", ignore_errors=True)
        shutil.rmtree(root / ".dvc" / "cache", ignore_errors=True)
        (root / ".dvc" / "config.local").unlink(missing_ok=True)
        self.sh("git", "init", "-q")
        self.commit("base")

    def sh(self, *cmd, cwd=None):
        r = subprocess.run(cmd, cwd=cwd or self.root, env=self.env, capture_output=True, text=True)
        assert r.returncode == 0, f"{cmd}: {r.stdout}\n{r.stderr}"
        return r.stdout

    def commit(self, message, cwd=None):
        self.sh("git", "add", "-A", cwd=cwd)
        self.sh("git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", message, cwd=cwd)


# the campaign stage at its smallest: one world
TINY_CAMPAIGN = ["campaign.worlds=1", "campaign.duration=6.0"]
SMALL = [a for o in TINY_SIM + TINY_CAMPAIGN for a in ("-S", o)]


@pytest.fixture(scope="module")
def dvc_repo(tmp_path_factory):
    env = dict(os.environ, PATH=str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""),
               DVC_NO_ANALYTICS="1", PYTHONHASHSEED="0")
    repo = DvcRepo(tmp_path_factory.mktemp("dvc") / "repo", env)
    out = repo.sh("dvc", "exp", "run", *SMALL)
    assert "Running stage 'evaluate@physics'" in out and "Running stage 'campaign'" in out
    return repo


@pytest.mark.slow
def test_dvc_reruns_only_the_model_whose_settings_changed(dvc_repo):
    sh = dvc_repo.sh
    out = sh("dvc", "exp", "run", *SMALL, "-S", "models.physics.substeps=2")
    assert "Running stage 'evaluate@physics':" in out
    for other in ("simulate", "extract", "sync", "filter", "split", "identify", "evaluate@naive", "evaluate@oracle",
                  "train@lstm", "evaluate@lstm", "campaign"):
        assert f"Running stage '{other}'" not in out
    # evaluate@physics, its export and MCU run, the report, the comparison with the paper and the
    # recordings that show every model
    for stage in ("export@physics", "mcu@physics", "report", "compare", "visualize"):
        assert f"Running stage '{stage}'" in out
    assert out.count("Running stage") == 6, out
    # back to the earlier value: restored from the run cache, not recomputed
    out = sh("dvc", "exp", "run", *SMALL, "-S", "models.physics.substeps=1")
    assert "Stage 'evaluate@physics' is cached - skipping run" in out
    assert "Running stage" not in out
    # the launcher is no parameter of the campaign: its results are the same wherever it runs
    out = sh("dvc", "exp", "run", *SMALL, "-S", "launcher=slurm")
    assert "Running stage" not in out


@pytest.mark.slow
def test_queued_experiments_run_side_by_side_and_reuse_the_run_cache(dvc_repo):
    sh = dvc_repo.sh
    for hidden in (40, 44):
        sh("dvc", "exp", "run", "--queue", *SMALL, "-S", f"models.lstm.network.hidden={hidden}", "-n", f"h{hidden}")
    sh("dvc", "exp", "run", "--run-all", "-j", "2")
    status = sh("dvc", "queue", "status")
    assert status.count("Success") == 2 and "Failed" not in status, status
    # both reused the pipeline's run cache: a learned model's setting retrains and re-evaluates that
    # model alone (with its export, MCU run, the report, the comparison and the recordings)
    for name in ("h40", "h44"):
        log = sh("dvc", "queue", "logs", name)
        for stage in ("simulate", "extract", "sync", "filter", "split", "identify", "campaign", "train@residual"):
            assert f"Running stage '{stage}'" not in log, (name, stage)
        assert "Running stage 'train@lstm'" in log and "Running stage 'evaluate@lstm'" in log
        assert log.count("Running stage") == 7, log
    # and a queued run's results come back from the shared run cache in the workspace
    out = sh("dvc", "exp", "run", *SMALL, "-S", "models.lstm.network.hidden=40")
    assert "Stage 'train@lstm' is cached - skipping run" in out and "Running stage" not in out


@pytest.mark.slow
def test_outputs_and_run_cache_round_trip_through_a_remote(dvc_repo, tmp_path):
    sh = dvc_repo.sh
    remote = tmp_path / "remote"
    sh("dvc", "remote", "add", "-d", "store", str(remote))
    dvc_repo.commit("results")
    sh("dvc", "push", "--run-cache")
    clone = tmp_path / "clone"
    sh("git", "clone", "-q", str(dvc_repo.root), str(clone))
    sh("dvc", "pull", "--run-cache", cwd=clone)
    status = sh("dvc", "status", cwd=clone)
    assert "up to date" in status, status
    out = sh("dvc", "repro", cwd=clone)
    assert "Running stage" not in out, out
    assert (clone / "reports" / "campaign" / "summary.json").read_bytes() == \
        (dvc_repo.root / "reports" / "campaign" / "summary.json").read_bytes()
