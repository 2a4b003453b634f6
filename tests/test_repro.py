"""``make repro``'s runner: the DAG's independent stages side by side, DVC's record the same."""

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from nanosysid.repro import StageRun, best_order, critical_order, makespan, run_graph
from toyrepo import env as toy_env, repro as _repro, toy_repo as _toy_repo

# a diamond under a lone stage:  a -> (b, c) -> d,  e alone
DIAMOND = {"a": set(), "b": {"a"}, "c": {"a"}, "d": {"b", "c"}, "e": set()}


def test_the_longest_chain_of_work_starts_first():
    seconds = {"a": 10, "b": 100, "c": 5, "d": 1, "e": 50}
    # chains by hand: a 10+100+1 = 111, b 101, e 50, c 6, d 1
    assert critical_order(DIAMOND, seconds) == ["a", "b", "e", "c", "d"]
    # unknown times count 1 s each: a's chain of three first, then b and c (two), ties by name
    assert critical_order(DIAMOND, {}) == ["a", "b", "c", "d", "e"]


# make repro's shape on two cores: a chain of preprocessing (a), a campaign that needs nothing,
# three trainings on a's output, and a report on everything
TRAINING = {"a": set(), "camp": set(), "L": {"a"}, "P": {"a"}, "R": {"a"}, "z": {"camp", "L", "P", "R"}}
TRAINING_S = {"a": 100, "camp": 150, "L": 400, "P": 300, "R": 250, "z": 10}


def test_the_order_that_ends_first_is_chosen_over_the_longest_chain():
    crit = critical_order(TRAINING, TRAINING_S)
    assert crit[:2] == ["a", "L"]
    # by hand, longest chain first: a 0-100 and camp 0-150; L 100-500 on a's slot, P 150-450 on
    # camp's; R waits for P, 450-700; z 700-710
    assert makespan(TRAINING, TRAINING_S, crit) == pytest.approx(710)
    # the best: P 100-400 and R 400-650 on a's slot, L 150-550 on camp's; z 650-660 (the trainings'
    # 950 s split 550 + 400 after the slots free at 100 and 150: no split ends sooner)
    best = best_order(TRAINING, TRAINING_S)
    assert makespan(TRAINING, TRAINING_S, best) == pytest.approx(660)
    # and run_graph keeps to it: the stages start in the hand schedule's sequence
    run, log, _ = _fake({s: v / 400 for s, v in TRAINING_S.items()})
    run_graph(TRAINING, run, jobs=2, order=best, progress=False, say=lambda s: None)
    starts = [s for what, s in log if what == "start"]
    assert sorted(starts[:2]) == ["a", "camp"] and starts[2:] == ["P", "L", "R", "z"]
    # without times nothing tells the orders apart: the longest chain first
    assert best_order(TRAINING, {}) == critical_order(TRAINING, {})


def _fake(times, fail=()):
    lock, live, log = threading.Lock(), set(), []
    peak = [0]

    def run(stage):
        with lock:
            live.add(stage)
            peak[0] = max(peak[0], len(live))
            log.append(("start", stage))
        time.sleep(times.get(stage, 0.05))
        with lock:
            live.discard(stage)
            log.append(("end", stage))
        return StageRun(3 if stage in fail else 0, times.get(stage, 0.05))

    return run, log, peak


@pytest.mark.parametrize("jobs", [1, 2, 3])
def test_stages_start_after_all_they_depend_on_and_never_more_than_jobs_at_once(jobs):
    run, log, peak = _fake({"b": 0.2, "c": 0.2, "e": 0.2})
    done, failed = run_graph(DIAMOND, run, jobs=jobs, progress=False, say=lambda s: None)
    assert failed is None and set(done) == set(DIAMOND)
    at = {(what, s): i for i, (what, s) in enumerate(log)}
    for s, ups in DIAMOND.items():
        for u in ups:
            assert at[("end", u)] < at[("start", s)], (u, s)
    assert peak[0] == min(jobs, 3)  # b, c and e can run at once, never more


def test_after_a_failure_no_stage_starts_and_the_first_failure_is_named():
    run, log, _ = _fake({"c": 0.05, "e": 0.3}, fail={"c"})
    done, failed = run_graph(DIAMOND, run, jobs=2, order=["a", "c", "e", "b", "d"], progress=False,
                             say=lambda s: None)
    assert failed == "c" and done["c"].rc == 3
    assert "d" not in done and "b" not in done  # b was ready when c failed, and was not started
    assert done["e"].rc == 0  # what was running finishes


def test_a_dependency_outside_the_graph_is_refused():
    with pytest.raises(ValueError, match=r"not in the graph: \['z'\]"):
        run_graph({"a": {"z"}}, lambda s: StageRun(0, 0.0), progress=False, say=lambda s: None)


@pytest.fixture
def env():
    return toy_env()


def test_independent_stages_of_a_dvc_pipeline_run_side_by_side_and_dvc_records_them_all(tmp_path, env):
    root = tmp_path / "toy"
    _toy_repo(root, env)
    r = _repro(root, env)
    assert r.returncode == 0, r.stdout + r.stderr
    t = {s: [float(x) for x in (root / f"{s}.txt").read_text().split()] for s in "abcd"}
    assert t["b"][0] < t["c"][1] and t["c"][0] < t["b"][1], t  # b and c overlapped
    assert t["d"][0] >= max(t["b"][1], t["c"][1]) and min(t["b"][0], t["c"][0]) >= t["a"][1], t
    status = subprocess.run([sys.executable, "-m", "dvc", "status"], cwd=root, env=env, capture_output=True,
                            text=True)
    assert "up to date" in status.stdout, status.stdout  # dvc.lock holds every stage, as `dvc repro` writes it
    record = json.loads((root / "rec.json").read_text())
    assert set(record["stages"]) == set("abcd") and record["jobs"] == 2 and record["skipped"] == []
    assert record["total_s"] < record["stages"]["b"] + record["stages"]["c"]  # the overlap saved time
    again = _repro(root, env)
    assert again.returncode == 0 and "0 stages ran, 4 skipped" in again.stdout, again.stdout + again.stderr
    assert json.loads((root / "rec.json").read_text()) == record  # the record is the last run that ran a stage


def test_each_pipeline_file_runs_apart_and_the_run_names_what_the_other_would_rerun(tmp_path, env):
    root = tmp_path / "toy"
    _toy_repo(root, env, campaign=True)
    r = _repro(root, env)
    assert r.returncode == 0, r.stdout + r.stderr
    assert not (root / "e.txt").exists() and not (root / "campaign" / "dvc.lock").exists()
    assert "campaign/dvc.yaml: would rerun e (`make campaign`)" in r.stdout, r.stdout
    lock = (root / "dvc.lock").read_text()
    c = _repro(root, env, "--pipeline", "campaign/dvc.yaml")
    assert c.returncode == 0, c.stdout + c.stderr
    assert (root / "e.txt").exists() and "e:" in (root / "campaign" / "dvc.lock").read_text()
    assert (root / "dvc.lock").read_text() == lock and "dvc.yaml: up to date" in c.stdout, c.stdout
    record = json.loads((root / "rec.json").read_text())
    assert list(record["stages"]) == ["campaign/dvc.yaml:e"] and "--pipeline campaign/dvc.yaml" in record["command"]
    status = subprocess.run([sys.executable, "-m", "dvc", "status"], cwd=root, env=env, capture_output=True,
                            text=True)
    assert "up to date" in status.stdout, status.stdout
    # `make campaign` is this call on the project's campaign pipeline
    makefile = (Path(__file__).resolve().parents[1] / "Makefile").read_text()
    recipe = makefile[makefile.index("\ncampaign:"):].split("\n\n")[0]
    assert "-m nanosysid.repro --pipeline campaign/dvc.yaml" in recipe, recipe


def test_a_failing_stage_stops_the_run_with_its_log_and_runs_nothing_after_it(tmp_path, env):
    root = tmp_path / "toy"
    _toy_repo(root, env, fail="c")
    r = _repro(root, env)
    assert r.returncode != 0
    assert "stage c failed" in r.stderr and "stage c broke on purpose" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert (root / "b.txt").exists() and not (root / "d.txt").exists() and not (root / "rec.json").exists()


def test_a_lock_file_cut_short_is_put_back_from_its_last_whole_copy(tmp_path):
    from nanosysid.repro import keep_whole, repair_lock

    lock, good = tmp_path / "dvc.lock", tmp_path / "whole" / "dvc.lock"
    whole = "schema: '2.0'\nstages:\n  a:\n    cmd: python a.py\n"
    lock.write_text(whole)
    keep_whole(lock, good)
    assert good.read_text() == whole and not repair_lock(lock, good)  # a whole file is left alone
    for cut in ("schema: '2.0'\nstages:\n  a:\n    cmd: pyth", "", "schema: '2.0'\nstages:\n  a: [b\n"):
        lock.write_text(cut)
        keep_whole(lock, good)  # a cut file is never kept
        assert good.read_text() == whole
        assert repair_lock(lock, good) and lock.read_text() == whole


def test_dvcs_rwlock_cut_short_is_removed_and_a_whole_one_kept(tmp_path):
    from nanosysid.repro import repair_rwlock

    rw = tmp_path / "rwlock"
    rw.write_text('{"read": {}, "write": {"a.txt": {"pid": 1, "cmd": "dvc repro"}}}')
    assert not repair_rwlock(rw) and rw.exists()
    rw.write_text('{"read": {}, "wri')
    assert repair_rwlock(rw) and not rw.exists()
    assert not repair_rwlock(rw)  # none at all: nothing to do


def test_make_repro_and_make_test_write_no_tracked_file_and_install_only_what_is_missing():
    root = Path(__file__).resolve().parents[1]
    plan = subprocess.run(["make", "-n", "-B", "repro", "test"], cwd=root, capture_output=True, text=True,
                          check=True).stdout
    # system packages only where the toolchain is missing: apt is named only in the branch after
    # the toolchain's own check (pip installs into .venv)
    lines = plan.splitlines()
    for i, line in enumerate(lines):
        if "apt-get" in line:
            check = next(x for x in reversed(lines[:i]) if x.startswith("if "))
            assert line.startswith("elif") and check.startswith("if command -v arm-none-eabi-gcc"), (line, check)
    assert "nanosysid.report.readme" not in plan  # the README is regenerated by `make readme` only
    out = plan.split("nanosysid.repro", 1)[1].split("--out", 1)[1].split()[0]
    ignored = subprocess.run(["git", "check-ignore", "-q", out], cwd=root)
    assert ignored.returncode == 0, f"{out}: the run times' record would be a tracked file"
    # the explicit target is the one that installs the toolchain
    assert "apt-get" in subprocess.run(["make", "-n", "toolchain"], cwd=root, capture_output=True, text=True).stdout


def test_make_quick_composes_the_profile_and_runs_both_pipelines_without_the_rigs_stages(capsys):
    # the profile's stages are the tests' tiny pipeline (tests/test_dvc.py runs it through DVC)
    root = Path(__file__).resolve().parents[1]
    plan = subprocess.run(["make", "-n", "-B", "quick"], cwd=root, capture_output=True, text=True, check=True).stdout
    lines = plan.splitlines()
    compose = next(i for i, x in enumerate(lines) if "nanosysid.config compose profile=quick" in x)
    (run,) = [i for i, x in enumerate(lines) if "nanosysid.repro" in x]
    command = lines[run] + " " + lines[run + 1]
    assert compose < run and "--skip-rig" in command, plan
    assert "--pipeline dvc.yaml" in command and "--pipeline campaign/dvc.yaml" in command, plan
    out = command.split("--out", 1)[1].split()[0]
    assert subprocess.run(["git", "check-ignore", "-q", out], cwd=root).returncode == 0, out
    from nanosysid.repro import _with_rig

    graph = {"split": set(), "rig_fetch": set(), "rig_split": {"rig_fetch"}, "report": {"split"},
             "rig_report": {"rig_split", "report"}}
    assert _with_rig(graph, skip=True) == {"split": set(), "report": {"split"}}
    assert "rig pipeline skipped: --skip-rig" in capsys.readouterr().out


def test_make_repro_stops_before_any_stage_where_it_cannot_install_the_toolchain(tmp_path):
    """Not root and no toolchain: `make repro`'s first step stops with the command and the setting,
    and lets a configuration without the microcontroller through."""
    root = Path(__file__).resolve().parents[1]
    shim = tmp_path / "bin"
    shim.mkdir()
    (shim / "id").write_text("#!/bin/sh\necho 1000\n")  # `id -u` of a user who is not root
    (shim / "id").chmod(0o755)
    env = {"PATH": f"{shim}:/usr/bin:/bin", "HOME": str(tmp_path)}
    run = subprocess.run(["make", "-s", "toolchain-ready", "HAVE_TOOLCHAIN=false"], cwd=root, env=env,
                         capture_output=True, text=True)
    assert run.returncode != 0
    assert "make toolchain" in run.stdout and "export.mcu.enabled: false" in run.stdout, run.stdout
    off = subprocess.run(["make", "-s", "toolchain-ready", "HAVE_TOOLCHAIN=false", "MCU_ENABLED=false"], cwd=root,
                         env=env, capture_output=True, text=True)
    assert off.returncode == 0, off.stdout + off.stderr
