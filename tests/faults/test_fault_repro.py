"""``make repro`` stopped at any point (Ctrl-C, SIGTERM, SIGKILL, at start-up or with stages
running) leaves ``dvc.lock`` whole, and the next ``make repro`` goes on to an up-to-date
pipeline; two runners in one repository never run at once."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time

import pytest
import yaml

from toyrepo import env as toy_env, repro, start, toy_repo, up_to_date

CLASS = "data loss"


@pytest.fixture
def env():
    return toy_env()


def lock_whole(root) -> bool:
    lock = root / "dvc.lock"
    return not lock.exists() or isinstance(yaml.safe_load(lock.read_text())["stages"], dict)


def test_an_interruption_that_lands_in_a_callback_at_start_up_still_stops_the_runner(tmp_path, env):
    # Ctrl-C while an import's module-lock weakref callback runs: Python swallows the handler's
    # SystemExit there (printing it with a traceback) and goes on; made to happen on purpose here,
    # the runner still stops before any stage, without a traceback
    root = tmp_path / "toy"
    toy_repo(root, env)
    code = ("import sys, weakref\n"
            "import nanosysid.repro as r\n"
            "sys.unraisablehook = r._unraisable\n"
            "class A: pass\n"
            "a = A(); ref = weakref.ref(a, lambda _: r._quit_starting(signal_number, None)); del a\n"
            "sys.exit(r.main(['--jobs', '2', '--out', 'rec.json']))\n").replace("signal_number", str(int(signal.SIGINT)))
    run = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True)
    assert run.returncode == 130 and "interrupted before any stage started" in run.stderr, run.stderr
    assert "Traceback" not in run.stderr, run.stderr
    assert not (root / "rec.json").exists() and not list(root.glob("*.txt")) and lock_whole(root)


@pytest.mark.parametrize("sig, after", [(signal.SIGINT, 1.5), (signal.SIGINT, 4.0), (signal.SIGTERM, 3.0)],
                         ids=["SIGINT at start-up", "SIGINT with b and c running", "SIGTERM with a stage running"])
def test_an_interrupted_run_leaves_dvc_lock_whole_and_the_next_one_goes_on(tmp_path, env, sig, after):
    root = tmp_path / "toy"
    toy_repo(root, env)
    runner = start(root, env)
    time.sleep(after)
    runner.send_signal(sig)
    out, err = runner.communicate(timeout=120)
    assert runner.returncode in (0, 130) and "Traceback" not in err, err
    if runner.returncode == 130:
        assert "interrupted" in err and not (root / "rec.json").exists()
    assert lock_whole(root)
    # no stage's call outlives the runner: nothing is written after it has returned
    written = {f: f.stat().st_mtime_ns for f in root.glob("*.txt")}
    time.sleep(2.5)
    assert {f: f.stat().st_mtime_ns for f in root.glob("*.txt")} == written
    again = repro(root, env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert up_to_date(root, env)


def live_calls(root) -> list[str]:
    live = root / ".dvc/tmp/repro/live.json"
    try:
        return sorted(json.loads(live.read_text())["calls"])
    except (FileNotFoundError, ValueError):
        return []


@pytest.mark.parametrize("when", ["start-up", "b and c running", "near the end"])
def test_a_runner_killed_outright_leaves_a_run_the_next_one_finishes(tmp_path, env, when):
    """SIGKILL reaches the runner alone: its stage calls (sessions of their own) run on. The next
    runner stops those still running, by name, then runs what is left; dvc.lock ends whole and up
    to date."""
    root = tmp_path / "toy"
    toy_repo(root, env)
    runner = start(root, env)
    if when == "b and c running":  # each has 2 s of sleep left: the next run finds both
        deadline = time.monotonic() + 60
        while live_calls(root) != ["b", "c"] and time.monotonic() < deadline:
            time.sleep(0.02)
    else:
        time.sleep({"start-up": 1.0, "near the end": 4.5}[when])
    runner.kill()
    runner.communicate(timeout=60)
    left = live_calls(root)
    again = repro(root, env)
    assert again.returncode == 0 and "Traceback" not in again.stderr, again.stdout + again.stderr
    stopped = re.search(r"its stages still running were stopped: ([a-z, ]+);", again.stderr)
    stopped = stopped.group(1).split(", ") if stopped else []
    # a call may end on its own between the kill and the next run; none that was not running is named
    assert set(stopped) <= set(left), again.stderr
    if when == "b and c running":
        assert stopped == ["b", "c"], again.stderr
    assert lock_whole(root) and up_to_date(root, env)
    assert not (root / ".dvc/tmp/repro/live.json").exists()


def test_a_second_runner_beside_a_running_one_is_refused_in_one_line(tmp_path, env):
    root = tmp_path / "toy"
    toy_repo(root, env)
    first = start(root, env)
    try:
        deadline = time.monotonic() + 30
        while not (root / ".dvc/tmp/repro/live.json").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        second = repro(root, env)
        assert second.returncode == 2 and "Traceback" not in second.stderr
        assert re.fullmatch(rf"error: another `make repro` \(process {first.pid}\) is running in this repository: "
                            r"wait for it to end, or stop it \(Ctrl-C, or kill -INT it\)\n", second.stderr), second.stderr
    finally:
        first.communicate(timeout=120)
    assert first.returncode == 0 and up_to_date(root, env)
