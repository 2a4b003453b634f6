"""DVC's dependencies of every stage are the modules its script imports (the import graph of
:mod:`nanosysid.depgraph`, which writes them), so the run cache never serves a result computed
by other code and an edit reruns no stage that does not run it; and discovery never imports the
simulator. ``python -m nanosysid.depgraph write`` rewrites them after an import changes.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import yaml

from nanosysid.depgraph import ONE_MODEL, PIPELINES, imported_files, stages, written_deps

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"


def uncovered(files: set[Path], deps: list[str]) -> list[str]:
    paths = [(ROOT / d).resolve() for d in deps]
    return sorted(str(f.relative_to(ROOT)) for f in files
                  if not any(f == p or p in f.parents for p in paths))


def every_stage(root: Path = ROOT) -> dict[str, tuple[str, list[str]]]:
    """Every pipeline's stages, :func:`stages`' entries under DVC's names for them (``train``,
    ``campaign/dvc.yaml:campaign``)."""
    return {(name if pipeline == "dvc.yaml" else f"{pipeline}:{name}"): entry
            for pipeline in PIPELINES for name, entry in stages(root, pipeline).items()}


def expanded() -> dict[str, list[str]]:
    """Every stage of every pipeline as DVC runs it (``train@lstm``), with its deps resolved."""
    from dvc.repo import Repo

    with Repo(str(ROOT)) as repo:
        return {s.addressing: [str(Path(d.def_path)) for d in s.deps] for s in repo.index.stages}


@pytest.mark.parametrize("stage", sorted(every_stage()))
def test_stage_depends_on_every_module_it_imports(stage):
    module, deps = every_stage()[stage]
    # a stage that runs one model imports the networks by name at run time: that model's own is
    # its code entry (checked with the resolved stages below), the others are no dependency
    missing = uncovered(imported_files(module, loaded_by_name=module not in ONE_MODEL), deps)
    assert not missing, f"stage {stage!r} imports {missing} but does not depend on them"


def test_a_stage_of_one_model_depends_on_that_models_code_and_no_other_networks():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    networks = {str(p.relative_to(ROOT)) for p in (SRC / "nanosysid/models/components").glob("*.py")} - {
        "src/nanosysid/models/components/__init__.py", "src/nanosysid/models/components/mlp.py"}  # lstm builds on mlp
    checked = 0
    for stage, deps in expanded().items():
        script, _, name = stage.partition("@")
        if every_stage()[script][0] not in ONE_MODEL:
            continue
        # a stage of the models it names: one (its foreach item), or the window track's
        names = [name] if name else params["window"]["models"]
        own = set()
        for model in (params["models"][n] for n in names):
            network = (model.get("network") or {}).get("name")
            own |= {f"src/nanosysid/models/components/{network}.py"} if network else set()
            assert model["code"] in deps, (stage, model["code"])
        assert {d for d in deps if d in networks} == (own & networks), (stage, deps)
        checked += 1
    assert checked >= 20


def test_the_check_sees_a_removed_dependency():
    module, deps = stages()["report"]
    assert not uncovered(imported_files(module), deps)
    for dep in ("src/nanosysid/report/tables.py", "src/nanosysid/metrics.py"):  # imported directly, and through another
        assert dep in uncovered(imported_files(module), [d for d in deps if d != dep])


def test_lazy_imports_are_followed():
    # the config module reads the flights' sample period inside a function
    files = {str(f.relative_to(ROOT)) for f in imported_files("nanosysid.config")}
    assert "src/nanosysid/dataio.py" in files


@pytest.mark.parametrize("pipeline", PIPELINES)
def test_the_pipelines_deps_are_the_import_graphs(pipeline):
    text = (ROOT / pipeline).read_text()
    assert written_deps(text, pipeline=pipeline) == text, \
        f"{pipeline}'s deps differ from the import graph: python -m nanosysid.depgraph write"


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


def copied(tmp_path: Path, env: dict):
    """A copy of the project's code, settings and pipelines with their locks (no outputs) as its
    own git repository, and a function running a command in it."""
    import shutil
    import subprocess

    from dvcenv import copy_model_code

    repo = tmp_path / "repo"
    repo.mkdir()
    for item in ("dvc.yaml", "dvc.lock", "rig", "campaign", "params.yaml", "params-rig.yaml", "conf", "stages", "src",
                 ".dvcignore", ".gitignore"):
        (shutil.copytree if (ROOT / item).is_dir() else shutil.copy)(ROOT / item, repo / item,
                                                                      **({"ignore": shutil.ignore_patterns("__pycache__")}
                                                                         if (ROOT / item).is_dir() else {}))
    copy_model_code(ROOT, repo)
    (repo / ".dvc").mkdir()
    shutil.copy(ROOT / ".dvc" / "config", repo / ".dvc" / "config")

    def sh(*cmd):
        r = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True)
        assert r.returncode == 0, f"{cmd}: {r.stdout}\n{r.stderr}"
        return r.stdout

    sh("git", "init", "-q")
    return repo, sh


def fingerprints(root: Path) -> dict[str, str]:
    """Every stage of ``root``'s pipelines (DVC's names for them) and what DVC compares before it
    reruns one: its command, its file dependencies' bytes (None where absent: no stage has run in
    a copy) and its params' values. Two trees' fingerprints differ for the stages a change between
    them reruns, whether or not a stage was already out of date (a user's tree with models of its
    own that never ran)."""
    import contextlib
    import hashlib
    import json

    from dvc.dependency.param import ParamsDependency
    from dvc.repo import Repo

    got = {}
    with contextlib.chdir(root), Repo(str(root)) as repo:  # DVC names a stage from the working directory
        for stage in repo.index.stages:
            parts = []
            for dep in stage.deps:
                if isinstance(dep, ParamsDependency):
                    parts.append((str(dep.def_path), json.dumps(dep.read_params(), sort_keys=True, default=str)))
                else:
                    path = Path(dep.fs_path)
                    parts.append((str(dep.def_path), hashlib.md5(path.read_bytes()).hexdigest() if path.is_file()
                                  else None))
            got[stage.addressing] = json.dumps([stage.cmd, sorted(parts, key=str)])
    return got


def test_adding_the_readmes_example_model_reruns_its_own_stages_the_report_and_the_recordings(tmp_path, venv_env):
    from nanosysid import config
    from test_config import readme_model

    repo, _ = copied(tmp_path, venv_env)
    before = fingerprints(repo)
    # the README's three files, then `make params` and `make deps`
    gru, (component, model_yaml, config_lines, _) = readme_model()
    (repo / f"src/nanosysid/models/components/{gru}.py").write_text(component)
    (repo / f"conf/model/{gru}.yaml").write_text(model_yaml)
    defaults_line, learned_line = [line for line in config_lines.splitlines() if line.strip()]
    text = (repo / "conf/config.yaml").read_text()
    text = text.replace("  - _self_\n", f"{defaults_line}\n  - _self_\n", 1)
    (repo / "conf/config.yaml").write_text(text.replace("\nlearned:\n", f"\nlearned:\n{learned_line}\n", 1))
    config.compose([], out=repo / "params.yaml", conf_dir=repo / "conf")
    config.compose([], out=repo / "params-rig.yaml", conf_dir=repo / "conf", root="rig")
    for pipeline in PIPELINES:
        (repo / pipeline).write_text(written_deps((repo / pipeline).read_text(), root=repo, pipeline=pipeline))
    # the suite's dependency checks hold in the copy
    for stage, (module, deps) in every_stage(repo).items():
        files = imported_files(module, repo, loaded_by_name=module not in ONE_MODEL)
        paths = [(repo / d).resolve() for d in deps]
        assert all(any(f == p or p in f.parents for p in paths) for f in files), stage
    after = fingerprints(repo)
    stale = {name for name in after if after[name] != before.get(name)}
    # its own stages (the simulated world's and the rig's training, its evaluation), and those
    # that read every model: the reports, the recordings and the rig's comparison with the paper
    # (whose settings hold every model); no other model is trained or scored
    assert stale == {f"train@{gru}", f"evaluate@{gru}", f"rig/dvc.yaml:rig_train@{gru}", f"rig/dvc.yaml:rig_evaluate@{gru}",
                     "report", "visualize",
                     "rig/dvc.yaml:rig_report", "rig/dvc.yaml:rig_visualize", "rig/dvc.yaml:rig_compare"}, stale


@pytest.mark.parametrize("params, source", [("params.yaml", "dvc.yaml"), ("params-rig.yaml", "rig/dvc.yaml")])
def test_an_ablation_reruns_stages_of_the_source_whose_settings_it_changes_only(tmp_path, venv_env, params, source):
    """`dvc exp run -S <params file>:models.physics.substeps=4` (the README's ablation, on either
    source): the physics model's own evaluation of that source goes out of date, and no stage of
    the other source's pipeline."""
    import json

    repo, sh = copied(tmp_path, venv_env)
    path = repo / params
    cfg = yaml.safe_load(path.read_text())
    cfg["models"]["physics"]["substeps"] = 4
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    status = json.loads(sh("dvc", "status", "--json"))
    stale = {name for name, entries in status.items() for e in entries
             if isinstance(e, dict) and isinstance(e.get("changed deps", {}).get(params), dict)}
    own = {name for name in stale if (name.partition(":")[0] if ":" in name else "dvc.yaml") == source}
    assert stale == own, f"an edit of {params} puts another pipeline's stages out of date: {sorted(stale - own)}"
    evaluate = "evaluate@physics" if source == "dvc.yaml" else "rig/dvc.yaml:rig_evaluate@physics"
    assert evaluate in stale and not any("train@" in name or "evaluate@lstm" in name for name in stale), stale
    if source == "rig/dvc.yaml":
        # the guide's ablation of the rig names these very stages (every one reads the changed setting)
        import docpages

        line = next(x for x in docpages.text().splitlines()
                    if x.startswith("dvc exp run rig/dvc.yaml -S params-rig.yaml:models.physics.substeps=4"))
        claimed = {f"rig/dvc.yaml:{s}" for s in line.split("reruns", 1)[1].strip().split(", ")}
        assert claimed == stale, (claimed, stale)


@pytest.mark.parametrize("module", ["src/nanosysid/preprocess/sync.py", "src/nanosysid/effects.py",
                                    "src/nanosysid/discover/fit.py"])
def test_changing_a_module_puts_exactly_the_stages_that_import_it_out_of_date(tmp_path, venv_env, module):
    import json

    repo, sh = copied(tmp_path, venv_env)
    with open(repo / module, "a") as f:
        f.write("\n# changed\n")
    status = json.loads(sh("dvc", "status", "--json"))
    stale = {name.split("@")[0] for name, entries in status.items() for e in entries
             if isinstance(e, dict) and module in e.get("changed deps", {})}
    importers = {name for name, (script, _) in every_stage().items() if ROOT / module in imported_files(script)}
    assert stale == importers
    if "discover" in module:
        # discovery, what scores, exports and reports its model, and the campaign (its own
        # pipeline) that judges it
        assert {"discover", "campaign/dvc.yaml:campaign"} <= stale
        assert not stale & {"train", "identify", "quality", "split", "simulate", "extract"}


def test_the_committed_lock_records_the_committed_code():
    # a stage whose lock entry records another version of a file it reads is out of date in a
    # fresh clone: `dvc status` is not clean and the first `make repro` reruns it and rewrites
    # dvc.lock. Every file dependency git tracks is checked against its md5 (DVC's file hash).
    import hashlib
    import subprocess

    tracked = set(subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                                 check=True).stdout.split())
    entries = [(f"{pipeline}:{name}", stage) for pipeline in PIPELINES
               for name, stage in yaml.safe_load((ROOT / pipeline).with_name("dvc.lock").read_text())["stages"].items()]
    assert {name.partition(":")[0] for name, _ in entries} == set(PIPELINES), "a pipeline's dvc.lock is empty"
    md5 = {}
    stale = []
    for name, stage in entries:
        for dep in stage.get("deps", []):
            path = dep["path"]
            if path not in tracked or "md5" not in dep:
                continue
            if path not in md5:
                md5[path] = hashlib.md5((ROOT / path).read_bytes()).hexdigest()
            if dep["md5"] != md5[path]:
                stale.append(f"{name}: {path}")
    assert md5, "no tracked file dependency found in dvc.lock"
    assert not stale, f"a dvc.lock records other versions of: {', '.join(stale[:10])} (+{max(len(stale) - 10, 0)})"
