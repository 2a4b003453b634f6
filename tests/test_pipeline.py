"""Each stage on a tiny case in a temporary folder, and the DVC pipeline's caching."""

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from nanosysid import config
from nanosysid.cli import run_stage
from stages import evaluate, simulate, split

ROOT = Path(__file__).resolve().parents[1]


def tiny(tmp_path, *extra):
    """Stage arguments for a tiny synthetic case in tmp_path: a composed params file plus overrides."""
    params = tmp_path / "params.yaml"
    if not params.exists():
        config.compose(["sim.generator=synthetic"], out=params, conf_dir=ROOT / "conf")
    return [
        "--params", str(params),
        f"sim.out_dir={tmp_path / 'raw'}",
        f"data.flights_dir={tmp_path / 'raw'}",
        f"paths.split={tmp_path / 'split'}",
        f"paths.eval={tmp_path / 'eval'}",
        f"paths.sim_report={tmp_path / 'sim'}",
        "sim.synthetic.samples=150",
        "sim.runs={square: 1, random: 0, chirp: 1, melon: 2}",
        *extra,
    ]


def test_stages_on_a_tiny_case(tmp_path):
    assert run_stage(simulate.main, description="", argv=tiny(tmp_path)) == 0
    assert sorted(p.name for p in (tmp_path / "raw").rglob("*.csv")) == [
        "chirp_20250601_run1.csv", "melon_20250601_run1.csv", "melon_20250601_run2.csv", "square_20250601_run1.csv"
    ]
    assert run_stage(split.main, description="", argv=tiny(tmp_path)) == 0
    summary = json.loads((tmp_path / "split" / "split.json").read_text())
    assert summary["train"]["samples"] == 300 and summary["test"]["samples"] == 300
    scores = {}
    for model in ("naive", "physics", "physics_full"):
        assert run_stage(evaluate.main, description="", name_arg="model", argv=[model, *tiny(tmp_path)]) == 0
        m = json.loads((tmp_path / "eval" / model / "metrics.json").read_text())
        assert m["n_windows"] == 2 * (150 - 50) and len(m["mae"]["p"]) == 50
        assert set(m["per_flight"]) == {"melon_20250601_run1", "melon_20250601_run2"}
        scores[model] = m["simerr"]
        table = (tmp_path / "eval" / model / "table.md").read_text()
        assert f"| {model} |" in table
    # the data follow the nominal dynamics, which physics_full integrates with 1 RK4 step
    # per sample where the data used 4: small but nonzero error
    assert scores["physics_full"]["p"] < 1e-3 * scores["naive"]["p"]
    assert scores["physics"]["p"] < 0.2 * scores["naive"]["p"]


def test_simulate_stage_writes_the_published_layout_and_statistics(tmp_path):
    params = tmp_path / "params.yaml"
    config.compose([], out=params, conf_dir=ROOT / "conf")  # the default data: the simulator
    args = [
        "--params", str(params), f"sim.out_dir={tmp_path / 'raw'}", f"paths.sim_report={tmp_path / 'sim'}",
        "sim.runs={square: 0, random: 0, chirp: 1, melon: 1}", "sim.flight.preroll=0.5",
        "sim.flight.trajectories.chirp.duration=2.0",
        "sim.flight.trajectories.melon={duration: 2.0, circle_time: 1.0, return_time: 0.5}",
    ]
    assert run_stage(simulate.main, description="", argv=args) == 0
    files = sorted(str(p.relative_to(tmp_path / "raw")) for p in (tmp_path / "raw").rglob("*.csv"))
    assert files == ["test/melon_20250601_run1.csv", "train/chirp_20250601_run1.csv"]
    stats = (tmp_path / "sim" / "stats.md").read_text()
    assert "| melon | 2.00 / 65.00 (0.03 ✗)" in stats and "| chirp |" in stats


def test_failing_split_keeps_previous_output_and_names_the_file(tmp_path, capsys):
    assert run_stage(simulate.main, description="", argv=tiny(tmp_path)) == 0
    assert run_stage(split.main, description="", argv=tiny(tmp_path)) == 0
    before = sorted(p.relative_to(tmp_path) for p in (tmp_path / "split").rglob("*"))
    bad = tmp_path / "raw" / "test" / "melon_20250601_run2.csv"
    bad.write_text(bad.read_text().replace("\n", "\n,,,\n", 1))
    assert run_stage(split.main, description="", argv=tiny(tmp_path)) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and str(bad) in err and "column 't', row 0" in err
    assert sorted(p.relative_to(tmp_path) for p in (tmp_path / "split").rglob("*")) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_stage_runs_as_a_module_with_overrides(tmp_path, venv_env):
    run_stage(simulate.main, description="", argv=tiny(tmp_path))
    run_stage(split.main, description="", argv=tiny(tmp_path))
    r = subprocess.run(
        ["python", "-m", "stages.evaluate", "naive", *tiny(tmp_path, "eval.horizon=10")],
        cwd=ROOT, env=venv_env, capture_output=True, text=True,
    )
    assert r.returncode == 0, r.stderr
    m = json.loads((tmp_path / "eval" / "naive" / "metrics.json").read_text())
    assert m["horizon"] == 10 and m["n_windows"] == 2 * 140


def test_unknown_model_is_one_clear_error(tmp_path, capsys):
    assert run_stage(evaluate.main, description="", name_arg="model", argv=["lstmx", *tiny(tmp_path)]) == 2
    assert "models.lstmx: no such model" in capsys.readouterr().err


@pytest.mark.slow
def test_dvc_reruns_only_the_model_whose_settings_changed(tmp_path, venv_env):
    repo = tmp_path / "repo"
    repo.mkdir()
    for item in ("dvc.yaml", "params.yaml", "conf", "stages", "src", ".dvc", ".dvcignore", ".gitignore"):
        src = ROOT / item
        (shutil.copytree if src.is_dir() else shutil.copy)(src, repo / item)
    shutil.rmtree(repo / ".dvc" / "tmp", ignore_errors=True)
    shutil.rmtree(repo / ".dvc" / "cache", ignore_errors=True)

    def sh(*cmd):
        r = subprocess.run(cmd, cwd=repo, env=venv_env, capture_output=True, text=True)
        assert r.returncode == 0, f"{cmd}: {r.stdout}\n{r.stderr}"
        return r.stdout

    sh("git", "init", "-q")
    sh("git", "-c", "user.name=t", "-c", "user.email=t@t", "add", "-A")
    sh("git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "base")
    small = ["-S", "sim.generator=synthetic", "-S", "sim.synthetic.samples=120",
             "-S", "sim.runs={square: 1, random: 0, chirp: 0, melon: 1}"]
    out = sh("dvc", "exp", "run", *small)
    assert "Running stage 'evaluate@physics'" in out and "Running stage 'evaluate@naive'" in out
    out = sh("dvc", "exp", "run", *small, "-S", "models.physics.substeps=2")
    assert "Running stage 'evaluate@physics':" in out
    for other in ("simulate", "split", "evaluate@naive", "evaluate@physics_full", "evaluate@oracle"):
        assert f"Running stage '{other}'" not in out
    # back to the earlier value: restored from the run cache, not recomputed
    out = sh("dvc", "exp", "run", *small, "-S", "models.physics.substeps=1")
    assert "Stage 'evaluate@physics' is cached - skipping run" in out
    assert "Running stage" not in out
