"""A toy DVC pipeline for ``make repro``'s runner: a -> (b, c) -> d, each stage sleeping, then
writing its start and end (wall clock) into its output."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from dvcenv import dvc_env

STAGE = """import sys, time
name, fail = sys.argv[1], sys.argv[2] == "fail"
t0 = time.time()
time.sleep(float(sys.argv[3]))
if fail:
    print("stage", name, "broke on purpose")
    sys.exit(3)
open(name + ".txt", "w").write(f"{t0} {time.time()}")
"""


def env() -> dict[str, str]:
    """The environment of a runner that imports this checkout's library."""
    src = str(Path(__file__).resolve().parents[1] / "src")
    return dvc_env(PYTHONPATH=src + os.pathsep + os.environ.get("PYTHONPATH", ""))


def toy_repo(root: Path, env: dict, fail: str = "", campaign: bool = False) -> None:
    """The pipeline in a new git and DVC repository at ``root``; the stage ``fail`` exits 3. With
    ``campaign``, a second pipeline file ``campaign/dvc.yaml`` (run at the root, as the
    project's) holds one stage ``e``."""
    root.mkdir()
    (root / "stage.py").write_text(STAGE)
    stages = {"a": ([], 0.0), "b": (["a.txt"], 2.0), "c": (["a.txt"], 2.0), "d": (["b.txt", "c.txt"], 0.0)}
    lines = ["stages:"]
    for name, (deps, sleep) in stages.items():
        mode = "fail" if name == fail else "ok"
        lines += [f"  {name}:", f"    cmd: {sys.executable} stage.py {name} {mode} {sleep}",
                  "    deps: [stage.py" + "".join(f", {d}" for d in deps) + "]", f"    outs: [{name}.txt]"]
    (root / "dvc.yaml").write_text("\n".join(lines) + "\n")
    if campaign:
        (root / "campaign").mkdir()
        (root / "campaign" / "dvc.yaml").write_text(
            f"stages:\n  e:\n    wdir: ..\n    cmd: {sys.executable} stage.py e ok 0.0\n    deps: [stage.py]\n"
            "    outs: [e.txt]\n")
    init(root, env)


def init(root: Path, env: dict) -> None:
    """A new git and DVC repository at ``root`` (the folder exists)."""
    for cmd in (["git", "init", "-q"], [sys.executable, "-m", "dvc", "init", "-q"]):
        subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True)


def start(root: Path, env: dict) -> subprocess.Popen:
    """The runner, started in the background."""
    return subprocess.Popen([sys.executable, "-m", "nanosysid.repro", "--jobs", "2", "--out", "rec.json"],
                            cwd=root, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def repro(root: Path, env: dict, *args: str) -> subprocess.CompletedProcess:
    """The runner, run to its end (``args`` after its own)."""
    return subprocess.run([sys.executable, "-m", "nanosysid.repro", "--jobs", "2", "--out", "rec.json", *args],
                          cwd=root, env=env, capture_output=True, text=True)


def up_to_date(root: Path, env: dict) -> bool:
    status = subprocess.run([sys.executable, "-m", "dvc", "status"], cwd=root, env=env, capture_output=True,
                            text=True)
    return "up to date" in status.stdout
