"""DVC's dependencies of every stage are the modules its script imports (the import graph of
:mod:`nanosysid.depgraph`, which writes them), so the run cache never serves a result computed
by other code and an edit reruns no stage that does not run it; and discovery never imports the
simulator. ``python -m nanosysid.depgraph write`` rewrites them after an import changes.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from nanosysid.depgraph import imported_files, stages, written_deps

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"


def uncovered(files: set[Path], deps: list[str]) -> list[str]:
    paths = [(ROOT / d).resolve() for d in deps]
    return sorted(str(f.relative_to(ROOT)) for f in files
                  if not any(f == p or p in f.parents for p in paths))


@pytest.mark.parametrize("stage", sorted(stages()))
def test_stage_depends_on_every_module_it_imports(stage):
    module, deps = stages()[stage]
    missing = uncovered(imported_files(module), deps)
    assert not missing, f"dvc.yaml: stage {stage!r} imports {missing} but does not depend on them"


def test_the_check_sees_a_removed_dependency():
    module, deps = stages()["export"]
    assert not uncovered(imported_files(module), deps)
    assert "src/nanosysid/effects.py" in uncovered(imported_files(module), [d for d in deps if d != "src/nanosysid/effects.py"])


def test_lazy_imports_are_followed():
    # the config module reads the flights' sample period inside a function
    files = {str(f.relative_to(ROOT)) for f in imported_files("nanosysid.config")}
    assert "src/nanosysid/dataio.py" in files


def test_dvc_yaml_deps_are_the_import_graphs():
    text = (ROOT / "dvc.yaml").read_text()
    assert written_deps(text) == text, "dvc.yaml's deps differ from the import graph: python -m nanosysid.depgraph write"


def test_nothing_trained_or_measured_before_training_imports_discovery_or_the_simulator():
    # an edit to discovery or to the simulated world must not retrain the networks or redo the data chain
    for stage in ("train", "identify", "quality", "split", "extract", "sync", "filter"):
        module, deps = stages()[stage]
        reached = [d for d in deps if d.startswith(("src/nanosysid/discover", "src/nanosysid/sim/", "src/nanosysid/export"))]
        assert not reached, f"{stage} depends on {reached}"


def test_discovery_never_imports_the_simulated_world():
    sim = SRC / "nanosysid" / "sim"
    for f in sorted((SRC / "nanosysid" / "discover").glob("*.py")):
        module = "nanosysid.discover" + ("" if f.stem == "__init__" else f".{f.stem}")
        reached = [str(p.relative_to(ROOT)) for p in imported_files(module) if sim in p.parents]
        assert not reached, f"{module} imports the simulator: {reached}"


@pytest.mark.parametrize("module", ["src/nanosysid/preprocess/sync.py", "src/nanosysid/effects.py",
                                    "src/nanosysid/discover/fit.py"])
def test_changing_a_module_puts_exactly_the_stages_that_import_it_out_of_date(tmp_path, venv_env, module):
    import json
    import shutil
    import subprocess

    repo = tmp_path / "repo"
    repo.mkdir()
    for item in ("dvc.yaml", "dvc.lock", "params.yaml", "params-rig.yaml", "conf", "stages", "src", ".dvcignore",
                 ".gitignore"):
        (shutil.copytree if (ROOT / item).is_dir() else shutil.copy)(ROOT / item, repo / item)
    (repo / ".dvc").mkdir()
    shutil.copy(ROOT / ".dvc" / "config", repo / ".dvc" / "config")

    def sh(*cmd):
        r = subprocess.run(cmd, cwd=repo, env=venv_env, capture_output=True, text=True)
        assert r.returncode == 0, f"{cmd}: {r.stdout}\n{r.stderr}"
        return r.stdout

    sh("git", "init", "-q")
    with open(repo / module, "a") as f:
        f.write("\n# changed\n")
    status = json.loads(sh("dvc", "status", "--json"))
    stale = {name.split("@")[0] for name, entries in status.items() for e in entries
             if isinstance(e, dict) and module in e.get("changed deps", {})}
    importers = {name for name, (script, _) in stages().items() if ROOT / module in imported_files(script)}
    assert stale == importers
    if "discover" in module:
        # discovery, what scores, exports and reports its model, and the campaign that judges it
        assert "discover" in stale and not stale & {"train", "identify", "quality", "split", "simulate", "extract"}
