"""The pipeline as DVC runs it: outputs and the run cache travel through a remote, only what changed
reruns, queued experiments share the run cache, and a user's own flights run through one experiment
without the simulator's stages. One repository for the first two and the third's flights (its base
run is the file's cost), the tests in that order."""

import shlex
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from dvcenv import copy_model_code, dvc_env
from nanosysid.errors import ToolchainError
from nanosysid.export.mcu import require_toolchain
from test_pipeline import TINY_SIM

ROOT = Path(__file__).resolve().parents[1]


class DvcRepo:
    """A copy of the project as its own git and DVC repository, with its own cache and without the
    real flights (the rig's pipeline, rig/dvc.yaml, is there and never runs: tests/test_rig.py)."""

    def __init__(self, root: Path, env: dict):
        self.root, self.env = root, env
        root.mkdir(parents=True)
        for item in ("dvc.yaml", "rig/dvc.yaml", "campaign/dvc.yaml", "params.yaml", "params-rig.yaml", "conf", "stages", "src", ".dvc", ".dvcignore",
                     ".gitignore"):
            (root / item).parent.mkdir(parents=True, exist_ok=True)
            src = ROOT / item
            if src.is_dir():  # the bytecode too (git ignores it): each stage's process reads it, not the sources
                shutil.copytree(src, root / item)
            else:
                shutil.copy(src, root / item)
        copy_model_code(ROOT, root)
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


# the README's first look (`make quick`): short flights flown eagerly, two epochs (the campaign's
# pipeline, with its one world, is make quick's too, and no part of this pipeline)
QUICK = ["profile=quick"]
# the export and MCU stages of one model: the others' are the same two DVC stages over another
# model's files (tests/test_pipeline.py runs them for a physics, a learned and a discovered model)
ONE_EXPORT = [f"~export.models.{m}" for m in ("residual", "phys_res", "lstm", "discovered")]


def _no_toolchain() -> list[str]:
    """The MCU stage switched off where the product's own check finds the ARM toolchain missing
    (compiler, emulator or newlib), as the README tells such a user."""
    try:
        require_toolchain()
    except ToolchainError:
        return ["export.mcu.enabled=false"]
    return []


NO_TOOLCHAIN = _no_toolchain()
SMALL = [a for o in QUICK + ONE_EXPORT + NO_TOOLCHAIN for a in ("-S", o)]


@pytest.fixture(scope="module")
def dvc_repo(tmp_path_factory):
    repo = DvcRepo(tmp_path_factory.mktemp("dvc") / "repo", dvc_env())
    out = repo.sh("dvc", "exp", "run", *SMALL)
    assert all(f"Running stage '{s}'" in out for s in ("evaluate@physics", "hypotheses")), out
    # the profile is the tests' tiny pipeline, and its report says it is no benchmark's
    params = yaml.safe_load((repo.root / "params.yaml").read_text())
    for override in TINY_SIM:
        key, _, value = override.partition("=")
        node = params
        for part in key.split("."):
            node = node[part]
        want = yaml.safe_load(value)
        assert ({k: node[k] for k in want} if isinstance(want, dict) else node) == want, override
    assert "not the benchmark's figures" in (repo.root / "reports" / "benchmark.md").read_text().split("##")[0]
    # the campaign is its own pipeline (tests/test_repro.py runs a second pipeline file apart, and
    # tests/test_launcher.py the campaign's stage): the benchmark's run leaves it out, and `dvc
    # status` names it
    assert "campaign" not in out and "campaign/dvc.yaml:campaign@sim" in repo.sh("dvc", "status")
    return repo


# each experiment's setting, and the stages it must rerun: the model's own and those that read
# every model's results (the report, the comparison with the paper, the recordings). A learned
# model's setting reruns its own stages alike (tests/test_dependencies.py checks them by `dvc
# status` on adding the README's model), so one experiment, the README's, is run here.
EXPERIMENTS = {
    # a physics setting: the model's evaluation, its export and MCU run, and the window track's
    "substeps": ("models.physics.substeps=4",
                 ("evaluate@physics", "export@physics", "mcu@physics", "report", "compare@sim", "visualize", "window")),
}


@pytest.mark.slow
def test_outputs_and_run_cache_round_trip_through_a_remote(dvc_repo, tmp_path):
    sh = dvc_repo.sh
    remote = tmp_path / "remote"
    sh("dvc", "remote", "add", "-d", "store", str(remote))
    dvc_repo.commit("results")
    sh("dvc", "push", "--run-cache")
    clone = tmp_path / "clone"
    sh("git", "clone", "-q", str(dvc_repo.root), str(clone))
    # the campaign's and the rig's pipelines never ran here (no lock, nothing to pull): the
    # simulated world's travels
    for other in ("campaign", "rig"):
        (clone / other / "dvc.yaml").unlink()
    sh("dvc", "pull", "--run-cache", cwd=clone)
    status = sh("dvc", "status", "dvc.yaml", cwd=clone)
    assert "up to date" in status, status
    out = sh("dvc", "repro", cwd=clone)
    assert "Running stage" not in out, out
    for made in ("reports/benchmark.md", "reports/hypotheses/result.json", "models/discovered/model.json"):
        assert (clone / made).read_bytes() == (dvc_repo.root / made).read_bytes(), made


@pytest.mark.slow
def test_queued_experiments_rerun_only_what_changed_and_share_the_run_cache(dvc_repo):
    sh = dvc_repo.sh
    # the README's sweep queues one experiment per value (left unrun here: three LSTM trainings)
    from test_readme import readme_commands

    (sweep,), (start,) = readme_commands("dvc exp run --queue"), readme_commands("dvc queue start")
    show = next(c for c in readme_commands("dvc exp show") if "Experiment" in c)
    sh(*shlex.split(sweep.replace("--queue", "--queue " + " ".join(shlex.quote(a) for a in SMALL))))
    assert sh("dvc", "queue", "status").count("Queued") == 3
    sh("dvc", "queue", "remove", "--queued")
    for name, (change, _) in EXPERIMENTS.items():
        sh("dvc", "exp", "run", "--queue", *SMALL, "-S", change, "-n", name)
    # the README's `dvc queue start -j 2`: workers in the background, which outlive the command
    # (and hold its output open) until they have been idle a while, so the command's output is
    # not waited for
    started = subprocess.run(shlex.split(start), cwd=dvc_repo.root, env=dvc_repo.env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    assert started.returncode == 0, f"{start}: exit {started.returncode}"
    # an experiment's git ref appears once its worker has collected it (a look at git costs
    # milliseconds, `dvc queue status` a second and a half of CPU): DVC's status is asked when the
    # ref is there, or every 15 s for a run that fails
    deadline, asked = time.monotonic() + 1200, time.monotonic()
    while time.monotonic() < deadline:
        done = all(sh("git", "for-each-ref", f"refs/exps/**/{name}").strip() for name in EXPERIMENTS)
        if done or time.monotonic() - asked > 15:
            status, asked = sh("dvc", "queue", "status"), time.monotonic()
            if "Queued" not in status and "Running" not in status:
                break
        time.sleep(0.5)
    assert status.count("Success") == len(EXPERIMENTS) and "Failed" not in status, status
    shown = sh(*shlex.split(show))  # the README's view of a sweep: each experiment by name, its setting, its SimErr
    assert all(f"[{name}]" in shown for name in EXPERIMENTS) and "simerr.lstm.R" in shown, shown
    untouched = ("simulate@sim", "extract@sim", "sync@sim", "filter@sim", "split", "identify", "discover",
                 "campaign/dvc.yaml:campaign@sim",
                 "train@residual", "train@lstm", "evaluate@naive", "evaluate@oracle", "evaluate@residual")
    for name, (_, reruns) in EXPERIMENTS.items():
        log = sh("dvc", "queue", "logs", name)
        for stage in untouched:
            assert f"Running stage '{stage}'" not in log, (name, stage)
        for stage in reruns:
            assert f"Running stage '{stage}'" in log, (name, stage)
        assert log.count("Running stage") == len(reruns), log
    # the queued run's results come back to the workspace (which holds the base's) from the shared
    # run cache, not recomputed; and the launcher is no parameter of any stage: a stage's results
    # are the same wherever its work runs (tests/test_launcher.py), so the run cache serves them.
    # The stage and those upstream of it: the others are as the base left them
    out = sh("dvc", "exp", "run", *SMALL, "-S", EXPERIMENTS["substeps"][0], "-S", "launcher=slurm",
             "evaluate@physics")
    assert "Stage 'evaluate@physics' is cached - skipping run" in out and "Running stage" not in out, out
    for pipeline in ("dvc.yaml", "campaign/dvc.yaml"):
        spec = yaml.safe_load((ROOT / pipeline).read_text())["stages"]
        assert not [n for n, st in spec.items() if any(str(p).startswith("launcher") for p in
                                                      st.get("do", st).get("params", []))], pipeline
    # the README's comparison of experiments: one quantity's SimErr per model, a column each
    import docpages

    line = next(x for x in docpages.text().splitlines() if x.startswith("dvc exp show "))
    table = sh(*shlex.split(line.split("#")[0]), "--csv").splitlines()
    header = table[0].split(",")
    shown = [c for c in header if c.startswith("simerr.") or "summary.json" in c]
    models = yaml.safe_load((dvc_repo.root / "params.yaml").read_text())["models"]  # a user's own too
    assert {"naive", "physics", "physics_full", "oracle", "residual", "phys_res", "lstm", "discovered"} <= set(models)
    assert sorted(shown) == sorted(f"simerr.{m}.R" for m in models), header
    # the experiment's name and DVC's own columns beside them; rows: the workspace, the base and
    # the experiment
    assert len(header) <= len(models) + 8 and len(table) >= 3, table


@pytest.mark.slow
def test_a_users_own_flights_run_through_one_experiment_without_the_simulators_stages(dvc_repo, tmp_path):
    # the base run's filtered flights brought as a user's: two flights of each of two trajectories
    # of the user's own names, in the published schema, named by the README's manifest, and the
    # yaw calibration flight k_M is identified on (3 s flights excite yaw too little), into a
    # project of their own where nothing has run: a simulator's stage the experiment kept would run
    from test_config import readme_blocks

    user = DvcRepo(tmp_path / "user", dvc_repo.env)
    own = user.root / "own"
    own.mkdir()
    manifest = next(b for b in readme_blocks("## Your own flights") if b.startswith("file,"))
    rows = [line.split(",") for line in manifest.splitlines()[1:]]
    assert [(t, r) for _, t, r in rows] == [("loop", "1"), ("loop", "2"), ("spiral", "1"), ("spiral", "2")]
    for (file, _, _), (src, k) in zip(rows, (("chirp", 1), ("chirp", 2), ("melon", 1), ("melon", 2))):
        (flight,) = (dvc_repo.root / "processed" / "flights").glob(f"{src}_*_run{k}.csv")
        (own / file).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(flight, own / file)
    (yaw,) = (dvc_repo.root / "processed" / "flights").glob("yawsweep_*_run1.csv")
    shutil.copy(yaw, own / "yaw.csv")
    (own / "manifest.csv").write_text(manifest + "yaw.csv,yawsweep,1\n")
    # without the microcontroller (export.mcu.enabled=false), as a user without the ARM toolchain
    # runs it; one epoch, and discovery without its leave-one-flight-out folds, to keep it short
    quick = ["-S", "trainer.every_model.epochs=1"]
    out = user.sh("dvc", "exp", "run", *SMALL, *quick, "-S", "discover.flights_out=false", "-S", "discover.sindy=false",
                  "-S", "data=csv", "-S", "data.flights_dir=own", "-S", "split.train=[loop,figure8]",
                  "-S", "split.test=[spiral]", "-S", "export.mcu.enabled=false", "-n", "own")
    ran = {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage")}
    assert {"split", "identify", "train@lstm", "evaluate@lstm", "discover", "report"} <= ran, ran
    # the simulator's recording chain, the stages that check against its truth, and the oracle
    # are no part of it
    simulator = {"simulate", "extract", "sync", "filter", "quality", "compare", "campaign"}
    assert not [s for s in ran if s.partition("@")[0] in simulator] and "evaluate@oracle" not in ran, ran
    # nor the rig's, whose pipeline file is there (a project without the real flights: its fetch
    # would fail), and the experiment is DVC's to list
    assert not [s for s in ran if "rig_" in s] and "own" in user.sh("dvc", "exp", "list"), ran
    stages = user.sh("dvc", "stage", "list", "--name-only").split()
    assert "evaluate@oracle" not in stages and not [s for s in stages if s.endswith("@sim")], stages
    split = yaml.safe_load((user.root / "processed" / "split" / "split.json").read_text())
    assert sorted(split["test"]["flights"]) == ["spiral_own_run1", "spiral_own_run2"], split
    assert sorted(split["train"]["flights"]) == ["loop_own_run1", "loop_own_run2"], split
    rows = [line.split("|")[1].strip() for line in
            (user.root / "reports" / "benchmark.md").read_text().split("## ")[1].splitlines() if line.startswith("| ")]
    assert {"physics", "residual", "phys_res", "lstm", "discovered"} <= set(rows) and not [r for r in rows
                                                                                       if r.startswith("oracle")]
    assert not (user.root / "raw" / "sim").exists()  # nothing simulated
