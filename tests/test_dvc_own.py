"""A user's own flights through one DVC experiment: the stages that need the simulator's truth
are no part of it. In a repository of its own, beside test_dvc.py's, so the two run side by side."""

import shutil

import pytest
import yaml

from dvcenv import dvc_env
from test_dvc import SMALL, DvcRepo


@pytest.fixture(scope="module")
def own_repo(tmp_path_factory):
    """The project as its own DVC repository, its tiny simulated flights made up to the filter
    stage: the flights a user brings here, and the simulator's stages already run (a user's
    experiment must not run them again)."""
    repo = DvcRepo(tmp_path_factory.mktemp("dvc") / "repo", dvc_env())
    out = repo.sh("dvc", "exp", "run", *SMALL, "filter")
    assert "Running stage 'filter'" in out and "Running stage 'split'" not in out, out
    return repo


@pytest.mark.slow
def test_a_users_own_flights_run_through_one_experiment_without_the_simulators_stages(own_repo):
    # two flights of each of two trajectories of the user's own names, in the published schema,
    # named by the README's manifest, and the yaw calibration flight k_M is identified on (3 s
    # flights excite yaw too little)
    from test_config import readme_blocks

    own = own_repo.root / "own"
    own.mkdir()
    manifest = next(b for b in readme_blocks("## Your own flights") if b.startswith("file,"))
    rows = [line.split(",") for line in manifest.splitlines()[1:]]
    assert [(t, r) for _, t, r in rows] == [("loop", "1"), ("loop", "2"), ("spiral", "1"), ("spiral", "2")]
    for (file, _, _), (src, k) in zip(rows, (("chirp", 1), ("chirp", 2), ("melon", 1), ("melon", 2))):
        (flight,) = (own_repo.root / "processed" / "flights").glob(f"{src}_*_run{k}.csv")
        (own / file).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(flight, own / file)
    (yaw,) = (own_repo.root / "processed" / "flights").glob("yawsweep_*_run1.csv")
    shutil.copy(yaw, own / "yaw.csv")
    (own / "manifest.csv").write_text(manifest + "yaw.csv,yawsweep,1\n")
    # without the microcontroller (export.mcu.enabled=false), as a user without the ARM toolchain
    # runs it; one epoch, and discovery without its leave-one-flight-out folds, to keep it short
    quick = [a for m in ("residual", "phys_res", "lstm") for a in ("-S", f"models.{m}.train.epochs=1")]
    out = own_repo.sh("dvc", "exp", "run", *SMALL, *quick, "-S", "discover.flights_out=false", "-S", "discover.sindy=false",
                      "-S", "data=csv", "-S", "data.flights_dir=own", "-S", "split.train=[loop,figure8]",
                      "-S", "split.test=[spiral]", "-S", "export.mcu.enabled=false", "-n", "own")
    ran = {line.split("'")[1] for line in out.splitlines() if line.startswith("Running stage")}
    assert {"split", "identify", "train@lstm", "evaluate@lstm", "discover", "report"} <= ran, ran
    # the stages that check against the simulator's truth, and the oracle, are no part of it
    assert not ran & {"simulate", "extract", "quality@sim", "compare@sim", "campaign@sim", "evaluate@oracle"}, ran
    stages = own_repo.sh("dvc", "stage", "list", "--name-only").split()
    assert "evaluate@oracle" not in stages and not [s for s in stages if s.endswith("@sim")], stages
    split = yaml.safe_load((own_repo.root / "processed" / "split" / "split.json").read_text())
    assert sorted(split["test"]["flights"]) == ["spiral_own_run1", "spiral_own_run2"], split
    assert sorted(split["train"]["flights"]) == ["loop_own_run1", "loop_own_run2"], split
    rows = [line.split("|")[1].strip() for line in
            (own_repo.root / "reports" / "benchmark.md").read_text().split("## ")[1].splitlines() if line.startswith("| ")]
    assert {"physics", "residual", "phys_res", "lstm", "discovered"} <= set(rows) and not [r for r in rows
                                                                                       if r.startswith("oracle")]
    own_repo.sh("git", "checkout", "--", "params.yaml")
    shutil.rmtree(own)
