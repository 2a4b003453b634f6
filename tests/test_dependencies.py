"""DVC's dependencies of every stage are the modules its script imports (the import graph of
:mod:`nanosysid.depgraph`, which writes them), so the run cache never serves a result computed
by other code and an edit reruns no stage that does not run it; and discovery never imports the
simulator. Each pipeline's code stage depends on every file its stage scripts import and writes
one digest per script; every other stage depends on its script's digest.
``python -m nanosysid.depgraph write`` rewrites them after an import changes.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

import yaml

from nanosysid.depgraph import (CODE_STAGES, DIGESTS, ONE_MODEL, PIPELINES, SELF, digest, digest_path, imported_files,
                                package_folder, stages, written_deps)

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"


def uncovered(files: set[Path], deps: list[str]) -> list[str]:
    paths = [(ROOT / d).resolve() for d in deps]
    return sorted(str(f.relative_to(ROOT)) for f in files
                  if not any(f == p or p in f.parents for p in paths))


def every_stage(root: Path = ROOT) -> dict[str, tuple[str, str, list[str]]]:
    """Every pipeline's stages but its code stage, under DVC's names for them (``train``,
    ``campaign/dvc.yaml:campaign``): ``(pipeline, script module, deps)``."""
    return {(name if pipeline == "dvc.yaml" else f"{pipeline}:{name}"): (pipeline, module, deps)
            for pipeline in PIPELINES for name, (module, deps) in stages(root, pipeline).items() if module != SELF}


def code_stage(pipeline: str, root: Path = ROOT) -> tuple[str, list[str], list[str]]:
    """A pipeline's code stage as its file declares it: the folder its command writes, the
    scripts it writes a digest of, and its deps."""
    entry = yaml.safe_load((root / pipeline).read_text())["stages"][CODE_STAGES[pipeline]]
    head, _, args = entry["cmd"].partition(f"python -m {SELF} digest ")
    folder, *scripts = args.split()
    return folder, scripts, entry["deps"]


def watched(pipeline: str, deps: list[str], root: Path = ROOT) -> set[str]:
    """A stage's deps with each digest replaced by the files it names (what the code stage
    watches for it)."""
    out = set()
    for d in deps:
        if d.startswith(DIGESTS[pipeline] + "/"):
            out |= {line.split("  ", 1)[1] for line in digest(Path(d).stem, root).splitlines()}
        else:
            out.add(d)
    return out


def expanded() -> dict[str, list[str]]:
    """Every stage of every pipeline as DVC runs it (``train@lstm``), with its deps resolved."""
    from dvc.repo import Repo

    with Repo(str(ROOT)) as repo:
        return {s.addressing: [str(Path(d.def_path)) for d in s.deps] for s in repo.index.stages}


@pytest.mark.parametrize("stage", sorted(every_stage()))
def test_stage_depends_on_every_module_it_imports(stage):
    pipeline, module, deps = every_stage()[stage]
    folder, scripts, code = code_stage(pipeline)
    # the stage depends on its script's digest, which its pipeline's code stage writes
    assert digest_path(pipeline, module) in deps and folder == DIGESTS[pipeline] and module in scripts, (deps, scripts)
    # a stage that runs one model imports the networks by name at run time: that model's own is
    # its code entry (checked with the resolved stages below), the others are no dependency
    files = imported_files(module, loaded_by_name=module not in ONE_MODEL)
    missing = uncovered(files, code)
    assert not missing, f"stage {stage!r} imports {missing} but its pipeline's code stage does not depend on them"
    # the digest names each of them with the md5 of its bytes, so it changes when any one does
    named = dict(reversed(line.split("  ", 1)) for line in digest(module).splitlines())
    assert {ROOT / f for f in named} == files
    assert all(md5 == hashlib.md5((ROOT / f).read_bytes()).hexdigest() for f, md5 in named.items())


@pytest.mark.parametrize("pipeline", PIPELINES)
def test_the_code_stage_depends_on_its_own_code_and_writes_a_digest_of_every_script(pipeline):
    _, scripts, code = code_stage(pipeline)
    assert not uncovered(imported_files(SELF), code)
    assert sorted(scripts) == sorted({module for _, (p, module, _) in every_stage().items() if p == pipeline})


def test_a_stage_of_one_model_depends_on_that_models_code_and_no_other_networks():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    networks = {str(p.relative_to(ROOT)) for p in (SRC / "nanosysid/models/components").glob("*.py")} - {
        "src/nanosysid/models/components/__init__.py", "src/nanosysid/models/components/mlp.py"}  # lstm builds on mlp
    checked = 0
    for stage, deps in expanded().items():
        script, _, name = stage.partition("@")
        if script not in every_stage() or every_stage()[script][1] not in ONE_MODEL:
            continue
        deps = watched(every_stage()[script][0], deps)
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
    module, _ = stages()["report"]
    _, _, deps = code_stage("dvc.yaml")
    # the code stage watches the package folders (two entries, a column each in `dvc exp show`)
    assert sorted(deps) == ["src/nanosysid", "stages"]
    assert not uncovered(imported_files(module), deps)
    without_library = uncovered(imported_files(module), ["stages"])
    for dep in ("src/nanosysid/report/tables.py", "src/nanosysid/metrics.py"):  # imported directly, and through another
        assert dep in without_library
    without_scripts = uncovered(imported_files(module), ["src/nanosysid"])
    assert "stages/report.py" in without_scripts and all(f.startswith("stages/") for f in without_scripts)


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
        reached = [d for d in watched("dvc.yaml", deps) if d.startswith(("src/nanosysid/discover", "src/nanosysid/sim/", "src/nanosysid/export"))]
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
                elif str(dep.def_path).startswith("digests/"):  # what the code stage would write there
                    parts.append((str(dep.def_path), digest(Path(dep.def_path).stem, root)))
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
    for stage, (pipeline, module, _) in every_stage(repo).items():
        files = imported_files(module, repo, loaded_by_name=module not in ONE_MODEL)
        paths = [(repo / d).resolve() for d in code_stage(pipeline, repo)[2]]
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

    def stale(status: dict, dep) -> set[str]:
        return {name.split("@")[0] for name, entries in status.items() for e in entries
                if isinstance(e, dict) and any(dep(d) and v == "modified" for d, v in e.get("changed deps", {}).items())}

    def run_code_stages():  # their digests of the copy's code, as the code stages write them
        for pipeline in PIPELINES:
            for script in code_stage(pipeline)[1]:
                (repo / digest_path(pipeline, script)).parent.mkdir(parents=True, exist_ok=True)
                (repo / digest_path(pipeline, script)).write_text(digest(script, repo))

    repo, sh = copied(tmp_path, venv_env)
    importers = {name for name, (_, script, _) in every_stage().items() if ROOT / module in imported_files(script)}
    code_stages = [CODE_STAGES[p] if p == "dvc.yaml" else f"{p}:{CODE_STAGES[p]}" for p in PIPELINES]
    # the code stages run on this tree's code (a user's tree may hold models of its own): nothing
    # is out of date for its code
    run_code_stages()
    sh("dvc", "commit", "-f", "-q", *code_stages)
    assert not stale(json.loads(sh("dvc", "status", "--json")), lambda d: True)
    with open(repo / module, "a") as f:
        f.write("\n# changed\n")
    # `dvc status` names the edited file's package folder under the code stages, which watch it ...
    assert stale(json.loads(sh("dvc", "status", "--json")), lambda d: d == package_folder(module)) == set(code_stages)
    # ... whose run changes the digests of exactly the scripts that import it
    run_code_stages()
    assert stale(json.loads(sh("dvc", "status", "--json")), lambda d: d.startswith("digests/")) == importers
    if "discover" in module:
        # discovery, what scores, exports and reports its model, and the campaign (its own
        # pipeline) that judges it
        assert {"discover", "campaign/dvc.yaml:campaign"} <= importers
        assert not importers & {"train", "identify", "quality", "split", "simulate", "extract"}


def folder_hash(folder: str, files: list[str], tmp: Path) -> str:
    """DVC's hash of a folder holding only ``files`` (paths under it, as git names them)."""
    import os
    import shutil

    from dvc_data.hashfile.build import build
    from dvc_data.hashfile.db import HashFileDB
    from dvc_objects.fs.local import LocalFileSystem
    from dvc_objects.fs.memory import MemoryFileSystem

    dest = tmp / folder
    for f in files:
        (tmp / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ROOT / f, tmp / f)
    _, _, obj = build(HashFileDB(MemoryFileSystem(), "/odb"), os.fspath(dest), LocalFileSystem(), "md5")
    return obj.hash_info.value


def test_the_committed_lock_records_the_committed_code(tmp_path):
    # a stage whose lock entry records another version of a file it reads is out of date in a
    # fresh clone: `dvc status` is not clean and the first `make repro` reruns it and rewrites
    # dvc.lock. Every file dependency git tracks is checked against its md5 (DVC's file hash),
    # and the code stages' package folders against DVC's hash of the files git tracks in them
    # (an untracked file there would make the lock one no clone reproduces).
    import hashlib
    import subprocess

    tracked = set(subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                                 check=True).stdout.split())
    entries = [(f"{pipeline}:{name}", stage) for pipeline in PIPELINES
               for name, stage in yaml.safe_load((ROOT / pipeline).with_name("dvc.lock").read_text())["stages"].items()]
    assert {name.partition(":")[0] for name, _ in entries} == set(PIPELINES), "a pipeline's dvc.lock is empty"
    folders = {d for pipeline in PIPELINES for d in code_stage(pipeline)[2]}  # the code stages' package folders
    md5 = {}
    stale = []
    for name, stage in entries:
        for dep in stage.get("deps", []):
            path = dep["path"]
            if path in folders:
                if path not in md5:
                    files = sorted(f for f in tracked if f.startswith(path + "/"))
                    md5[path] = folder_hash(path, files, tmp_path)
                if dep["md5"] != md5[path]:
                    stale.append(f"{name}: {path}")
                continue
            if path not in tracked or "md5" not in dep:
                continue
            if path not in md5:
                md5[path] = hashlib.md5((ROOT / path).read_bytes()).hexdigest()
            if dep["md5"] != md5[path]:
                stale.append(f"{name}: {path}")
    assert md5, "no tracked file dependency found in dvc.lock"
    assert not stale, f"a dvc.lock records other versions of: {', '.join(stale[:10])} (+{max(len(stale) - 10, 0)})"


def test_the_code_stage_refuses_to_run_while_its_pipeline_misses_a_script_or_a_package_folder(tmp_path, venv_env):
    # a stage script the code stage writes no digest of (a stage added by hand), or a package
    # folder it does not watch (an edit there would never rerun it, so never change a digest):
    # the stage refuses, names the fix and writes nothing
    import subprocess
    import sys

    repo, _ = copied(tmp_path, venv_env)
    _, scripts, _ = code_stage("dvc.yaml", repo)
    text = (repo / "dvc.yaml").read_text()
    head, sep, tail = text.partition("    deps:\n      - src/nanosysid\n      - stages\n")
    assert sep, "the code stage's deps are not the two package folders"
    for broken in (head + sep.replace("      - stages\n", "") + tail, text.replace(" stages.split ", " ", 1)):
        assert broken != text
        (repo / "dvc.yaml").write_text(broken)
        r = subprocess.run([sys.executable, "-m", SELF, "digest", DIGESTS["dvc.yaml"], *scripts], cwd=repo,
                           env=venv_env, capture_output=True, text=True)
        assert r.returncode == 2 and "make deps" in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert not (repo / DIGESTS["dvc.yaml"]).exists()
