"""DVC's dependencies of every stage cover every module its script imports, so the run cache
never serves a result computed by other code; and discovery never imports the simulator.

Imports are read from the source (``ast``), lazy imports inside functions included, and
followed through the project's own modules (``nanosysid`` and ``stages``); importing a
submodule runs its packages' ``__init__`` too, and a package that imports its modules by
name (``importlib.import_module(f"{__name__}.{name}")``, the networks) counts as importing
all of them. ``python tests/test_dependencies.py`` prints
each stage's modules, collapsed to folders where a whole package is imported.
"""

from __future__ import annotations

import ast
import re
import sys
from functools import lru_cache
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
OWN = ("nanosysid", "stages")


def module_file(name: str) -> Path | None:
    """The file of a project module or package, None for anything else."""
    if name.split(".")[0] not in OWN:
        return None
    base = (SRC if name.startswith("nanosysid") else ROOT) / Path(*name.split("."))
    for f in (base.with_suffix(".py"), base / "__init__.py"):
        if f.is_file():
            return f
    return None


def _parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


@lru_cache(maxsize=None)
def direct_imports(path: Path) -> frozenset[str]:
    """Project modules a file imports anywhere in its body."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            # `from package import module` imports the module
            names.update(f"{node.module}.{a.name}" for a in node.names if module_file(f"{node.module}.{a.name}"))
    out = set()
    for n in names:
        for m in (*_parents(n), n):
            if module_file(m):
                out.add(m)
    if path.name == "__init__.py" and "importlib.import_module(f\"{__name__}." in path.read_text():
        # a package that loads its modules by name (the networks) depends on all of them
        package = ".".join(path.relative_to(SRC if SRC in path.parents else ROOT).parent.parts)
        out.update(f"{package}.{f.stem}" for f in path.parent.glob("*.py") if f.stem != "__init__")
    return frozenset(out)


def imported_files(module: str) -> set[Path]:
    """Every project file that running ``python -m <module>`` imports (itself included)."""
    seen: set[str] = set()
    todo = [module, *_parents(module)]
    while todo:
        m = todo.pop()
        if m in seen or not module_file(m):
            continue
        seen.add(m)
        todo.extend(direct_imports(module_file(m)))
    return {module_file(m) for m in seen}


def stages() -> dict[str, tuple[str, list[str]]]:
    """``{stage: (script module, deps)}`` of dvc.yaml."""
    spec = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    out = {}
    for name, s in spec.items():
        body = s.get("do", s)
        module = re.search(r"python -m (\S+)", body["cmd"]).group(1)
        out[name] = (module, [d for d in body.get("deps", []) if "${" not in d])
    return out


def uncovered(files: set[Path], deps: list[str]) -> list[str]:
    paths = [(ROOT / d).resolve() for d in deps]
    return sorted(str(f.relative_to(ROOT)) for f in files
                  if not any(f == p or p in f.parents for p in paths))


def needed_deps(module: str) -> list[str]:
    """The files a stage imports, collapsed to folders where every module of a package is used."""
    files = imported_files(module)
    out: set[Path] = set()
    for f in files:
        pkg = f.parent
        while pkg != ROOT and pkg != SRC / "nanosysid" and (pkg / "__init__.py").exists() \
                and all(p in files for p in pkg.rglob("*.py")):
            f, pkg = pkg, pkg.parent
        out.add(f)
    return sorted(str(p.relative_to(ROOT)) for p in out)


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
    # the model registry imports the export and discovery code inside functions
    files = {str(f.relative_to(ROOT)) for f in imported_files("stages.evaluate")}
    assert {"src/nanosysid/export/cost.py", "src/nanosysid/discover/model.py", "src/nanosysid/sim/oracle.py"} <= files


def test_discovery_never_imports_the_simulated_world():
    sim = SRC / "nanosysid" / "sim"
    for f in sorted((SRC / "nanosysid" / "discover").glob("*.py")):
        module = "nanosysid.discover" + ("" if f.stem == "__init__" else f".{f.stem}")
        reached = [str(p.relative_to(ROOT)) for p in imported_files(module) if sim in p.parents]
        assert not reached, f"{module} imports the simulator: {reached}"


@pytest.mark.parametrize("module", ["src/nanosysid/bags/sync.py", "src/nanosysid/effects.py"])
def test_changing_a_module_puts_exactly_the_stages_that_import_it_out_of_date(tmp_path, venv_env, module):
    import json
    import shutil
    import subprocess

    repo = tmp_path / "repo"
    repo.mkdir()
    for item in ("dvc.yaml", "dvc.lock", "params.yaml", "conf", "stages", "src", ".dvcignore", ".gitignore"):
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


if __name__ == "__main__":
    for name, (module, _) in sorted(stages().items()):
        print(f"{name}:", *needed_deps(module), sep="\n  - ")
    sys.exit(0)
