"""The stages' code dependencies, from the import graph: what every ``python -m stages.<name>``
imports of the project.

Imports are read from the source (``ast``), lazy imports inside functions included, and
followed through the project's own modules (``nanosysid`` and ``stages``); importing a
submodule runs its packages' ``__init__`` too, and a package that imports its modules by name
(``importlib.import_module(f"{__name__}.{name}")``, the networks) counts as importing all of
them, except in a stage that runs one model (:data:`ONE_MODEL`), whose dvc.yaml entry names that
model's own code.

Each pipeline (:data:`PIPELINES`) has one code stage (:data:`CODE_STAGES`). It depends on the
folders of the packages the pipeline's stage scripts import (``src/nanosysid``, ``stages``), and
writes one digest per script (``digests/sim/stages.train.txt``: the md5 and path of each file
that script imports). Every other stage depends on its script's digest in place of the files
themselves: an edit reruns the code stage (seconds), which changes the digests of the scripts
that import the edited file and no other, so exactly the stages that run the edited code rerun.
One entry per stage instead of some forty keeps ``dvc.lock`` small, and DVC rewrites it after
every stage; one entry per package folder in the code stage keeps ``dvc exp show``, which has a
column for every file dependency, to two columns of code instead of a hundred.

Command line::

    python -m nanosysid.depgraph write    # rewrite every pipeline's code stage and code deps
    python -m nanosysid.depgraph check    # exit 1 when a pipeline differs from the import graph
    python -m nanosysid.depgraph digest digests/sim stages.a stages.b   # the code stage's command
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import re
import sys
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import yaml

from nanosysid.guard import PIPELINE_FILES

__all__ = ["module_file", "direct_imports", "by_name", "imported_files", "stages", "needed_deps", "written_deps",
           "digest", "write_digests", "digest_path", "code_deps", "package_folder", "ONE_MODEL", "PIPELINES",
           "CODE_STAGES", "DIGESTS", "SELF"]

OWN = ("nanosysid", "stages")
ROOT = Path(__file__).resolve().parents[2]  # the project: src/nanosysid/depgraph.py
CODE = ("src", "stages", "digests")  # the top folders of deps entries that are code, which the graph decides
# the project's pipelines, each with its own lock: the benchmark's on the simulated world and on the
# real flights (both `make repro`) and the campaign's (`make campaign`); every stage runs at the
# project's root (the others' ``wdir: ..``)
PIPELINES = (*PIPELINE_FILES, "campaign/dvc.yaml")
# each pipeline's code stage and the folder of digests it writes
CODE_STAGES = {"dvc.yaml": "code", "rig/dvc.yaml": "rig_code", "campaign/dvc.yaml": "campaign_code"}
DIGESTS = {"dvc.yaml": "digests/sim", "rig/dvc.yaml": "digests/rig", "campaign/dvc.yaml": "digests/campaign"}
SELF = "nanosysid.depgraph"  # the code stage's script


def _src(root: Path) -> Path:
    return root / "src"


def module_file(name: str, root: Path = ROOT) -> Path | None:
    """The file of a project module or package, None for anything else."""
    if name.split(".")[0] not in OWN:
        return None
    base = (_src(root) if name.startswith("nanosysid") else root) / Path(*name.split("."))
    for f in (base.with_suffix(".py"), base / "__init__.py"):
        if f.is_file():
            return f
    return None


def _parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


# the stages that run the models they name (one each in a foreach over the models; the window
# track's few): each depends on its models' own code through their ``code`` entries in dvc.yaml
# (the model's config names it), not on every network the components package can load by name,
# so adding or editing one network reruns its model's stages and those that load every model (the
# report, the recordings), no other
ONE_MODEL = ("stages.train", "stages.evaluate", "stages.export", "stages.mcu", "stages.window")


@lru_cache(maxsize=None)
def by_name(path: Path, root: Path = ROOT) -> frozenset[str]:
    """The modules a package's ``__init__`` loads by name
    (``importlib.import_module(f"{__name__}.{name}")``, the networks): all of its modules."""
    if path.name != "__init__.py" or "importlib.import_module(f\"{__name__}." not in path.read_text():
        return frozenset()
    src = _src(root)
    package = ".".join(path.relative_to(src if src in path.parents else root).parent.parts)
    return frozenset(f"{package}.{f.stem}" for f in path.parent.glob("*.py") if f.stem != "__init__")


@lru_cache(maxsize=None)
def direct_imports(path: Path, root: Path = ROOT) -> frozenset[str]:
    """Project modules a file imports anywhere in its body (those its package loads by name are
    :func:`by_name`'s)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            # `from package import module` imports the module
            names.update(f"{node.module}.{a.name}" for a in node.names if module_file(f"{node.module}.{a.name}", root))
    out = set()
    for n in names:
        for m in (*_parents(n), n):
            if module_file(m, root):
                out.add(m)
    return frozenset(out)


def imported_files(module: str, root: Path = ROOT, *, loaded_by_name: bool = True) -> set[Path]:
    """Every project file that running ``python -m <module>`` imports (itself included).
    ``loaded_by_name=False``: without the modules a package loads by name (:func:`by_name`),
    though with what they import (a network built on another's layers)."""
    seen: set[str] = set()
    todo = [module, *_parents(module)]
    while todo:
        m = todo.pop()
        if m in seen or not module_file(m, root):
            continue
        seen.add(m)
        f = module_file(m, root)
        todo.extend(direct_imports(f, root))
        for n in by_name(f, root):
            if loaded_by_name:
                todo.append(n)
            elif module_file(n, root):
                todo.extend(direct_imports(module_file(n, root), root))
    return {module_file(m, root) for m in seen}


def stages(root: Path = ROOT, pipeline: str = "dvc.yaml") -> dict[str, tuple[str, list[str]]]:
    """``{stage: (script module, deps)}`` of one pipeline file (``dvc.yaml``, :data:`PIPELINES`)."""
    spec = yaml.safe_load((root / pipeline).read_text())["stages"]
    out = {}
    for name, s in spec.items():
        body = s.get("do", s)
        module = re.search(r"python -m (\S+)", body["cmd"]).group(1)
        out[name] = (module, [d for d in body.get("deps", []) if "${" not in d])
    return out


def needed_deps(module: str, root: Path = ROOT) -> list[str]:
    """The files a stage imports, sorted; one entry per file, so that an edit to a module the
    stage does not import never reruns it. A stage of :data:`ONE_MODEL` leaves out the
    modules loaded by name: its model's own is its ``code`` entry."""
    return sorted(str(f.relative_to(root)) for f in imported_files(module, root, loaded_by_name=module not in ONE_MODEL))


def digest_path(pipeline: str, module: str) -> str:
    """The digest of a stage script in a pipeline (``digests/sim/stages.train.txt``)."""
    return f"{DIGESTS[pipeline]}/{module}.txt"


def package_folder(path: str) -> str:
    """The folder of the project package that holds a file (``src/nanosysid``, ``stages``)."""
    parts = Path(path).parts
    return "/".join(parts[:2] if parts[0] == "src" else parts[:1])


def code_deps(modules: Sequence[str], root: Path = ROOT) -> list[str]:
    """The package folders of every file the ``modules`` import, and of the code stage's own:
    the code stage's deps (DVC hashes a folder over its files, ``__pycache__`` left out by
    ``.dvcignore``)."""
    return sorted({package_folder(d) for m in (*modules, SELF) for d in needed_deps(m, root)})


def digest(module: str, root: Path = ROOT) -> str:
    """The md5 and path of every file ``python -m <module>`` imports (:func:`needed_deps`), a line
    each: it changes exactly when one of them does."""
    return "".join(f"{hashlib.md5((root / f).read_bytes()).hexdigest()}  {f}\n" for f in needed_deps(module, root))


def write_digests(folder: str | Path, modules: Sequence[str], root: Path = ROOT) -> None:
    """Write ``folder`` (relative to ``root``) whole: one digest per module, ``<module>.txt``."""
    from nanosysid.dataio import atomic_dir

    with atomic_dir(root / folder) as tmp:
        for m in modules:
            (tmp / f"{m}.txt").write_text(digest(m, root))


def written_deps(text: str, root: Path = ROOT, pipeline: str = "dvc.yaml") -> str:
    """A pipeline file's text (``pipeline``, whose text is ``text``) with its code entries
    replaced by the import graph's: the code stage's command names every stage script and its
    deps are every file they import; every other stage's code entry is its script's digest (the
    other entries, data and settings files, kept in their order after them)."""
    modules = {name: module for name, (module, _) in stages(root, pipeline).items()}
    own = sorted(set(modules.values()) - {SELF})  # the stage scripts, the code stage's aside
    lines = text.splitlines(keepends=True)
    out: list[str] = []
    stage = None
    i = 0
    while i < len(lines):
        line = lines[i]
        m = re.match(r"^  ([\w@-]+):\s*$", line)
        if m:
            stage = m.group(1)
        cm = re.match(rf"^(\s+cmd: python -m {re.escape(SELF)} digest)\b", line)
        if cm and modules.get(stage) == SELF:
            out.append(f"{cm.group(1)} {DIGESTS[pipeline]} {' '.join(own)}\n")
            i += 1
            continue
        dm = re.match(r"^(\s+)deps:\s*$", line)
        if dm and stage in modules:
            out.append(line)
            i += 1
            items = []
            while i < len(lines) and re.match(rf"^{dm.group(1)}  - ", lines[i]):
                items.append(lines[i])
                i += 1
            indent = dm.group(1) + "  - "
            kept = [it for it in items if it[len(indent):].strip().split("/")[0] not in CODE]
            code = code_deps(own, root) if modules[stage] == SELF else [digest_path(pipeline, modules[stage])]
            out += [f"{indent}{d}\n" for d in code] + kept
            continue
        out.append(line)
        i += 1
    return "".join(out)


def _digest(folder: str, modules: Sequence[str]) -> int:
    """The code stage: refuse where the pipeline's code stage no longer matches the import graph
    (a digest of a file the stage does not depend on would never change), else write."""
    root = Path.cwd()  # the project whose files DVC watches (a stage runs at its root), wherever this module is
    pipeline = next((p for p, f in DIGESTS.items() if f == folder), None)
    if pipeline is None:
        print(f"error: {folder}: no pipeline's digests folder (one of {', '.join(DIGESTS.values())})", file=sys.stderr)
        return 2
    text = (root / pipeline).read_text()
    if written_deps(text, root, pipeline) != text:
        print(f"error: {pipeline}: its code entries differ from the import graph; run `make deps` "
              "(python -m nanosysid.depgraph write)", file=sys.stderr)
        return 2
    from nanosysid.guard import stage_run

    with stage_run(CODE_STAGES[pipeline]):  # the folder's record names its stage
        write_digests(folder, modules, root)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nanosysid.depgraph", description=__doc__.split("\n")[0])
    parser.add_argument("command", choices=["write", "check", "digest"])
    parser.add_argument("args", nargs="*", help="digest: the folder, then the stage scripts")
    args = parser.parse_args(argv)
    if args.command == "digest":
        if not args.args:
            parser.error("digest needs the folder and the stage scripts")
        return _digest(args.args[0], args.args[1:])
    differ = []
    for pipeline in PIPELINES:
        path = ROOT / pipeline
        text = path.read_text()
        new = written_deps(text, pipeline=pipeline)
        if new == text:
            if args.command == "write":
                print(f"{pipeline}: deps match the import graph")
            continue
        differ.append(pipeline)
        if args.command == "write":
            path.write_text(new)
            print(f"{pipeline}: deps rewritten from the import graph")
    if args.command == "check" and differ:
        print(f"{', '.join(differ)}: deps differ from the import graph; run `python -m nanosysid.depgraph write`",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
