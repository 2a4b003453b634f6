"""``nanosysid <stage> [overrides]``: a pipeline stage from any directory.

The stage runs in the project it belongs to: the working directory where it holds a
``dvc.yaml`` (a project of your own), else the repository this package is installed from, so
its relative paths (``params.yaml``, the outputs) are the project's. ``nanosysid --help`` lists
the stages; ``nanosysid <stage> --help`` the stage's settings and the registered models.
"""

from __future__ import annotations

import os
import runpy
import sys
from pathlib import Path

__all__ = ["main", "project_root", "stage_names"]


def project_root(cwd: Path | None = None) -> Path:
    """The working directory where it holds a ``dvc.yaml`` and a ``stages/`` package, else the
    repository this package is installed from."""
    cwd = Path.cwd() if cwd is None else cwd
    if (cwd / "dvc.yaml").is_file() and (cwd / "stages").is_dir():
        return cwd
    return Path(__file__).resolve().parents[2]


def stage_names(root: Path) -> list[str]:
    """The stage scripts of ``root/stages``."""
    return sorted(p.stem for p in (root / "stages").glob("*.py") if p.stem not in ("__init__", "common"))


def from_here(overrides: list[str], here: Path, root: Path) -> list[str]:
    """The overrides with each relative path that exists in the user's working folder ``here``,
    and not in the project ``root`` the stage runs in, made absolute (a user's own folder)."""
    out = []
    for o in overrides:
        key, eq, value = o.partition("=")
        if eq and value and not Path(value).is_absolute() and here != root and (here / value).exists() \
                and not (root / value).exists():
            o = f"{key}={(here / value).resolve()}"
            print(f"nanosysid: {key}={value} is {o.partition('=')[2]} (relative to the working folder)", file=sys.stderr)
        out.append(o)
    return out


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        here = Path.cwd()
    except FileNotFoundError:
        print("nanosysid: the working folder no longer exists (deleted while in it); cd to a folder that does",
              file=sys.stderr)
        return 2
    root = project_root(here)
    names = stage_names(root) if (root / "stages").is_dir() else []
    if not names:
        print(f"nanosysid: {root} holds no stages/ (run it in a clone of the repository)", file=sys.stderr)
        return 2
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: nanosysid <stage> [overrides] [--params FILE]\n\n"
              f"Runs a stage of the pipeline in {root} (its params.yaml, its outputs).\n\n"
              f"stages: {', '.join(names)}\n\n`nanosysid <stage> --help`: the stage's settings and the registered models.")
        return 0
    stage = argv[0]
    if stage not in names:
        print(f"nanosysid: no stage {stage!r}; the stages are {', '.join(names)}", file=sys.stderr)
        return 2
    os.chdir(root)
    sys.path.insert(0, str(root))
    sys.argv = [f"nanosysid {stage}", *from_here(argv[1:], here, root)]
    try:
        runpy.run_module(f"stages.{stage}", run_name="__main__", alter_sys=True)
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
