"""A damaged object in DVC's cache is found by its bytes, not trusted by its name: DVC copies a
folder output's damaged file into the workspace and calls the pipeline up to date; ``make
repro``'s runner names it, removes it and runs the stage that wrote it again."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys

import pytest

from toyrepo import env as toy_env, init, repro, up_to_date

CLASS = "silent acceptance"

STAGE = """import os
os.makedirs("split", exist_ok=True)
open("split/train.csv", "w").write("t,x\\n0,1\\n")
open("split/test.csv", "w").write("t,x\\n0,2\\n")
"""


def dvc(root, env, *args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dvc", *args], cwd=root, env=env, capture_output=True, text=True)


@pytest.mark.parametrize("mtime", ["kept", "changed"], ids=["mtime kept", "mtime changed"])
def test_a_damaged_cache_object_checked_out_is_named_and_its_stage_runs_again(tmp_path, mtime):
    env = toy_env()
    root = tmp_path / "toy"
    root.mkdir()
    (root / "stage.py").write_text(STAGE)
    (root / "dvc.yaml").write_text(f"stages:\n  split:\n    cmd: {sys.executable} stage.py\n"
                                   "    deps: [stage.py]\n    outs: [split]\n")
    init(root, env)
    assert repro(root, env).returncode == 0
    good = (root / "split" / "test.csv").read_bytes()
    # the object of split/test.csv, named by the MD5 of its bytes ("t,x\n0,2\n", worked by hand below)
    md5 = hashlib.md5(b"t,x\n0,2\n").hexdigest()
    obj = root / ".dvc" / "cache" / "files" / "md5" / md5[:2] / md5[2:]
    assert obj.read_bytes() == good
    stamp = obj.stat()
    obj.chmod(0o644)
    obj.write_bytes(b"t,x\n0,9\n")
    if mtime == "kept":
        os.utime(obj, ns=(stamp.st_atime_ns, stamp.st_mtime_ns))
    shutil.rmtree(root / "split")
    assert dvc(root, env, "checkout").returncode == 0
    assert (root / "split" / "test.csv").read_bytes() == b"t,x\n0,9\n"  # DVC alone: copied as it is
    check = subprocess.run([sys.executable, "-m", "nanosysid.cachecheck"], cwd=root, env=env, capture_output=True,
                           text=True)
    assert check.returncode == 1 and "split/test.csv" in check.stderr and "Traceback" not in check.stderr, check.stderr
    assert obj.exists()  # the check alone removes nothing
    again = repro(root, env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "damaged DVC cache object" in again.stderr and "split/test.csv (stage split)" in again.stderr, again.stderr
    assert (root / "split" / "test.csv").read_bytes() == good
    assert (root / "split" / "train.csv").read_bytes() == b"t,x\n0,1\n"
    assert up_to_date(root, env)
    ok = subprocess.run([sys.executable, "-m", "nanosysid.cachecheck"], cwd=root, env=env, capture_output=True,
                        text=True)
    assert ok.returncode == 0, ok.stderr
