"""A stage stopped by a signal mid-work (SIGTERM from a scheduler, SIGINT from Ctrl-C) exits
non-zero with one line, writes no output and leaves the last run's as it was: a training stopped
so never exits 0 without its model (Lightning's own SIGTERM handler would let the fit end early
and the stage carry on)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

CLASS = "silent acceptance"

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent('''
    import sys, time
    from pathlib import Path
    from nanosysid import numerics
    numerics.pin()
    from nanosysid import dataio
    from stages.common import run_stage

    mode, out, ready = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])

    def main(cfg):
        if mode == "train":
            import torch
            from nanosysid import synthetic
            from nanosysid.models.training import train_model as train
            flights = synthetic.synthetic_flights([f"chirp_x_run{k}" for k in (1, 2, 3)], 400, seed=4)
            ready.touch()
            train({"name": "mlp", "options": {}}, flights, out, horizon=10, stride=5, batch_size=16,
                  epochs=10_000, patience=10_000, val_runs=[3], compile=False, progress=False)
        elif mode == "once":
            with dataio.atomic_file(out) as tmp:
                tmp.write_text('{"last": 1}')
        elif mode == "folder":
            with dataio.atomic_dir(out) as tmp:
                (tmp / "scores.json").write_text("{}")
                ready.touch()
                time.sleep(60)
        else:
            with dataio.atomic_file(out) as tmp:
                tmp.write_text("{}")
                ready.touch()
                time.sleep(60)

    main.__module__ = "stages.faulty"
    raise SystemExit(run_stage(main, description="", argv=["--params", sys.argv[4]]))
''')

# SIGHUP: the terminal or ssh session closed; a training (the longest write) is its case
CASES = [(sig, mode) for sig in (signal.SIGTERM, signal.SIGINT) for mode in ("file", "folder", "train")] + [
    (signal.SIGHUP, "train")]


def _as_from_a_terminal() -> None:
    for s in (signal.SIGINT, signal.SIGHUP):
        signal.signal(s, signal.SIG_DFL)


@pytest.mark.parametrize("sig,mode", CASES, ids=[f"{s.name} while writing a {m}" for s, m in CASES])
def test_a_stage_stopped_by_a_signal_exits_non_zero_and_writes_nothing(tmp_path, params, sig, mode):
    script = tmp_path / "stage.py"
    script.write_text(SCRIPT)
    out = tmp_path / ("model.pt" if mode == "train" else "scores.json" if mode == "file" else "eval")
    ready = tmp_path / "ready"
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{ROOT / 'src'}")
    if mode == "file":  # the last run's output, which must survive
        subprocess.run([sys.executable, str(script), "once", str(out), str(ready), str(params)], cwd=tmp_path, env=env,
                       check=True, capture_output=True)
        assert out.read_text() == '{"last": 1}'

    # as from a terminal: SIGINT and SIGHUP at their defaults (pytest-xdist's workers and jobs
    # started in the background ignore SIGINT, a suite run under nohup SIGHUP, and a stage leaves
    # an ignored signal ignored)
    p = subprocess.Popen([sys.executable, str(script), mode, str(out), str(ready), str(params)], cwd=tmp_path,
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=_as_from_a_terminal)
    deadline = time.monotonic() + 120
    while not ready.exists() and p.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert ready.exists(), p.communicate()
    time.sleep(1.0 if mode == "train" else 0.2)  # inside the fit, or inside the write
    p.send_signal(sig)
    try:
        _, err = p.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        p.kill()  # a stage the signal did not stop is no process to leave burning a core
        p.communicate()
        raise
    assert p.returncode == 128 + sig, (p.returncode, err)
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: ") and f"stopped by {sig.name}" in last, err
    assert "Traceback" not in err, err
    if mode == "file":
        assert out.read_text() == '{"last": 1}'
    else:
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == sorted(
        ["stage.py", "ready"] + ([out.name] if mode == "file" else [])), list(tmp_path.iterdir())


def test_a_stage_stopped_under_dvc_says_that_dvc_removed_the_last_runs_outputs(tmp_path, params):
    """DVC removes a stage's outputs before running it: "as they were" would be false there."""
    script = tmp_path / "stage.py"
    script.write_text(SCRIPT)
    out, ready = tmp_path / "scores.json", tmp_path / "ready"
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{ROOT / 'src'}", DVC_STAGE="train@residual")
    p = subprocess.Popen([sys.executable, str(script), "file", str(out), str(ready), str(params)], cwd=tmp_path,
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not ready.exists() and p.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 128 + signal.SIGTERM
    assert err.strip().splitlines()[-1].endswith(
        "its outputs were not written (DVC removed the last run's before starting it: `dvc checkout train@residual` "
        "brings them back from DVC's cache, `dvc repro` reruns the stage)"), err
