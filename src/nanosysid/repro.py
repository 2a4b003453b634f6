"""``make repro``: the DVC pipeline with its independent stages side by side.

``dvc repro`` runs one stage at a time, so on two cores the machine idles half of the time a
single-threaded stage runs, and the three trainings, the campaign and the evaluations wait
for each other although none reads another's outputs. DVC lets separate ``dvc repro <stage>``
calls on one repository run at once: each holds the repository's lock only to check and to
record its stage, not while the stage's command runs. ``python -m nanosysid.repro --jobs 2``
runs every stage of the benchmark's two pipeline files (``dvc.yaml``, the simulated world's, and
``rig/dvc.yaml``, the real flights') that way, as ``dvc --wait-for-lock repro --single-item
<stage>``, once every stage it depends on has finished, at most ``jobs`` at a time, in the
order whose schedule, played out with the stage times of the last record, ends first
(:func:`best_order`). ``--pipeline campaign/dvc.yaml`` runs the campaign's pipeline instead
(``make campaign``); each run ends with a line on what the other pipelines would rerun.

What it writes is what ``dvc repro`` writes: the same ``dvc.lock``, outputs and run cache; a
stage's bytes never depend on what runs beside it (each stage pins its own thread counts,
:mod:`nanosysid.numerics`). Two things are its own:

- while stages share the cores, OpenMP's waiting threads sleep instead of spinning
  (``OMP_WAIT_POLICY=PASSIVE``, a switch of speed only): a training's two spinning threads
  beside another busy process run several times slower than alone, sleeping ones about as
  fast as one thread;
- each stage's output goes to ``.dvc/tmp/repro/<stage>.log``; the console shows one line a
  stage and a progress bar, and the end of the log of a stage that fails.

An interruption (Ctrl-C, SIGINT or SIGTERM to the runner) stops the running stages through DVC's
own handling of SIGINT (each stage's call runs in its own session, so it gets the signal once,
from the runner), waits for them, and leaves ``dvc.lock`` whole: a copy is kept each time a
stage ends with the file whole, and a file cut short by the interruption is put back from it;
DVC's ``.dvc/tmp/rwlock`` cut short is removed.
The next ``make repro`` goes on from there (the stages that were stopped run again, or come
from DVC's run cache).

A runner killed outright (SIGKILL, the machine's out-of-memory killer) stops nothing: its calls
run on. The next runner finds them in ``.dvc/tmp/repro/live.json``, stops them as above, puts
``dvc.lock`` back where it was cut short, and goes on. While a runner is alive, a second one in
the same repository is refused (the two would run the same stages into the same outputs).

Before it starts, every cache object ``dvc.lock`` names is checked against its name
(:mod:`nanosysid.cachecheck`): a damaged one is removed, and the stage that wrote it runs again.

When every stage succeeds it writes the record of :mod:`nanosysid.report.runtimes` (each stage's
seconds, from its call's start to its end, the stages skipped or restored from the run cache,
and the total), with ``jobs``.
"""

from __future__ import annotations

import signal
import sys


_interrupted = False  # an interruption before any stage started, honoured before the first one starts


def _quit_starting(signum, frame):
    # an interruption before any stage has started: nothing to stop, nothing written
    global _interrupted
    _interrupted = True
    print("\ninterrupted before any stage started", file=sys.stderr)
    raise SystemExit(130)


def _unraisable(u) -> None:
    # the SystemExit above, raised while a callback that cannot raise ran (an import's module-lock
    # weakref): Python would print it with its traceback and go on; main stops before any stage
    if not (isinstance(u.exc_value, SystemExit) and _interrupted):
        sys.__unraisablehook__(u)


if __name__ == "__main__":  # from the start, not once the imports below are done
    signal.signal(signal.SIGINT, _quit_starting)
    signal.signal(signal.SIGTERM, _quit_starting)
    sys.unraisablehook = _unraisable

import argparse  # noqa: E402
import heapq  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections import deque  # noqa: E402
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable, Mapping, Sequence  # noqa: E402

from tqdm import tqdm  # noqa: E402

from nanosysid import cachecheck  # noqa: E402
from nanosysid.depgraph import PIPELINES  # noqa: E402
from nanosysid.guard import PIPELINE_FILES  # noqa: E402
from nanosysid.report.runtimes import SKIPPED, write_record  # noqa: E402

__all__ = ["StageRun", "stage_graph", "critical_order", "best_order", "makespan", "run_graph", "keep_whole",
           "repair_lock", "repair_rwlock", "stop_orphans", "RunnerBusy", "lock_of", "others_status", "main"]

LOG_DIR = Path(".dvc/tmp/repro")
LOCK = Path("dvc.lock")
GOOD_LOCK = LOG_DIR / "dvc.lock.whole"  # the last dvc.lock seen whole
# the running runner's process id and the process group of each stage call it has running: what
# the next runner stops where this one was killed outright (SIGKILL, a closed terminal's SIGHUP)
LIVE = LOG_DIR / "live.json"
STOP_GRACE_S = 60.0  # how long an interrupted stage's call has to stop before it is killed


@dataclass(frozen=True)
class StageRun:
    """How one stage's call ended: its exit status, seconds, and whether DVC skipped it."""

    rc: int
    seconds: float
    skipped: bool = False


def stage_graph(root: Path = Path("."), pipeline: str | Sequence[str] = "dvc.yaml") -> dict[str, set[str]]:
    """Each stage of the pipeline files of the repository (``train@lstm``;
    ``campaign/dvc.yaml:campaign@sim``) and the stages of those files it depends on, as DVC's own
    index sees them; stages without a command (``dvc add``-ed data) are left out."""
    from dvc.repo import Repo

    files = [pipeline] if isinstance(pipeline, str) else list(pipeline)
    with Repo(str(root)) as repo:
        graph = repo.index.graph  # an edge runs from a stage to a stage it depends on
        paths = {(Path(repo.root_dir) / f).resolve() for f in files}
        runnable = {s for s in graph.nodes if getattr(s, "cmd", None) and Path(s.dvcfile.path).resolve() in paths}
        return {s.addressing: {d.addressing for d in graph.successors(s) if d in runnable} for s in runnable}


# what each command runs: `make repro` the benchmark's two pipelines (the simulated world's and
# the rig's, side by side), `make campaign` the campaign's
RUNS = {"dvc.yaml": PIPELINE_FILES, "campaign/dvc.yaml": ("campaign/dvc.yaml",)}


# the command that runs each pipeline, for the line on what the others would rerun
COMMANDS = {"dvc.yaml": "make repro", "rig/dvc.yaml": "make repro", "campaign/dvc.yaml": "make campaign"}


def lock_of(pipeline: str) -> tuple[Path, Path]:
    """A pipeline file's ``dvc.lock`` and the path of its last whole copy."""
    lock = Path(pipeline).parent / "dvc.lock"
    return lock, LOG_DIR / (lock.as_posix().replace("/", "_") + ".whole")


def others_status(pipeline: str | Sequence[str], root: Path = Path(".")) -> list[str]:
    """One line per other pipeline of :data:`~nanosysid.depgraph.PIPELINES`: up to date, or the
    stages it would rerun and the command that runs them (``dvc status``'s answer)."""
    from dvc.repo import Repo

    ran = {f for p in ([pipeline] if isinstance(pipeline, str) else pipeline) for f in RUNS.get(p, (p,))}
    lines = []
    with Repo(str(root)) as repo:
        for other in PIPELINES:
            if other in ran or not (Path(repo.root_dir) / other).is_file():
                continue
            stale = sorted(name.partition(":")[2] or name for name in repo.status(targets=[other]))
            lines.append(f"{other}: " + (f"would rerun {', '.join(stale)} (`{COMMANDS.get(other, 'dvc repro ' + other)}`)"
                                         if stale else "up to date"))
    return lines


def critical_order(upstream: Mapping[str, set[str]], seconds: Mapping[str, float], default: float = 1.0) -> list[str]:
    """The stages by the work on the longest chain that starts with each (its own seconds and
    those of its longest chain of dependants), longest first, names breaking ties: starting the
    long chains early is what shortens the whole run."""
    below: dict[str, set[str]] = {s: set() for s in upstream}
    for s, ups in upstream.items():
        for u in ups:
            below[u].add(s)
    chain: dict[str, float] = {}

    def length(s: str) -> float:
        if s not in chain:
            chain[s] = seconds.get(s, default) + max((length(d) for d in below[s]), default=0.0)
        return chain[s]

    return sorted(upstream, key=lambda s: (-length(s), s))


def _ready(upstream: Mapping[str, set[str]], done: Mapping[str, object], busy: set[str],
           rank: Mapping[str, int]) -> list[str]:
    """The stages not started whose dependencies have all finished, by ``rank``."""
    return sorted((s for s in upstream if s not in done and s not in busy and all(u in done for u in upstream[s])),
                  key=lambda s: rank.get(s, len(rank)))


def makespan(upstream: Mapping[str, set[str]], seconds: Mapping[str, float], order: list[str], *, jobs: int = 2,
             default: float = 1.0) -> float:
    """When :func:`run_graph` would finish with ``order``, if every stage took its ``seconds``."""
    rank = {s: i for i, s in enumerate(order)}
    done: dict[str, float] = {}
    running: list[tuple[float, int, str]] = []  # (end, start sequence, stage): ties end in start order
    now, started = 0.0, 0
    while len(done) < len(upstream):
        busy = {s for _, _, s in running}
        for s in _ready(upstream, done, busy, rank)[: max(1, int(jobs)) - len(running)]:
            heapq.heappush(running, (now + seconds.get(s, default), started, s))
            started += 1
        if not running:
            raise ValueError(f"stages that never become ready: {sorted(set(upstream) - set(done))}")
        now, _, s = heapq.heappop(running)
        done[s] = now
    return now


def best_order(upstream: Mapping[str, set[str]], seconds: Mapping[str, float], *, jobs: int = 2,
               default: float = 1.0, longest: int = 5) -> list[str]:
    """The priority that ends the run first, when each stage takes its ``seconds``.

    The longest chain first (:func:`critical_order`) ignores that the slots are few: on two
    cores the campaign, which needs nothing, holds a slot from the start, and the training
    started on the slot it frees decides whether the last training starts early or late. So
    every ordering of the ``longest`` longest stages, ahead of the rest in critical order, is
    played out (:func:`makespan`), and the first that ends soonest is kept (the critical
    order on a tie, and when no stage has a time).
    """
    base = critical_order(upstream, seconds, default)
    heads = sorted(upstream, key=lambda s: (-seconds.get(s, default), s))[:longest]
    best, best_end = base, makespan(upstream, seconds, base, jobs=jobs, default=default)
    for head in itertools.permutations(heads):
        order = [*head, *(s for s in base if s not in head)]
        end = makespan(upstream, seconds, order, jobs=jobs, default=default)
        if end < best_end - 1e-9:
            best, best_end = order, end
    return best


def run_graph(upstream: Mapping[str, set[str]], run: Callable[[str], StageRun], *, jobs: int = 2,
              order: list[str] | None = None, progress: bool = True,
              say: Callable[[str], None] = print,
              stop: Callable[[], None] | None = None) -> tuple[dict[str, StageRun], str | None]:
    """Run every stage once all those it depends on have succeeded, at most ``jobs`` at a time,
    in ``order`` among the ready ones.

    Args:
        upstream: Each stage and the stages it depends on.
        run: Runs one stage (in a thread of this process) and says how it ended.
        order: The priority of the stages (default: their names' order).
        stop: Stops the running stages when the run is interrupted (KeyboardInterrupt), before
            it waits for them; the interruption is raised again once they have ended.

    Returns:
        What each stage that ran did, and the first stage that failed (None if none did); after
        a failure no new stage starts, those running finish.
    """
    unknown = sorted({u for ups in upstream.values() for u in ups} - set(upstream))
    if unknown:
        raise ValueError(f"stages depend on stages not in the graph: {unknown}")
    rank = {s: i for i, s in enumerate(order or sorted(upstream))}
    done: dict[str, StageRun] = {}
    failed: str | None = None
    running: dict[Future, str] = {}
    start = time.monotonic()
    bar = tqdm(total=len(upstream), desc="repro", unit="stage", disable=not progress, file=sys.stderr)
    with ThreadPoolExecutor(max_workers=max(1, int(jobs))) as pool:
        try:
            while True:
                if failed is None:
                    for s in _ready(upstream, done, set(running.values()), rank)[: max(1, int(jobs)) - len(running)]:
                        say(f"[{time.monotonic() - start:7.1f} s] {s}: running")
                        running[pool.submit(run, s)] = s
                if not running:
                    break
                bar.set_postfix_str(", ".join(sorted(running.values())))
                finished, _ = wait(list(running), return_when=FIRST_COMPLETED)
                for f in finished:
                    s = running.pop(f)
                    r = f.result()
                    done[s] = r
                    bar.update()
                    what = "skipped" if r.skipped else ("done" if r.rc == 0 else f"FAILED (exit {r.rc})")
                    say(f"[{time.monotonic() - start:7.1f} s] {s}: {what} in {r.seconds:.1f} s")
                    if r.rc != 0 and failed is None:
                        failed = s
        except KeyboardInterrupt:  # the running stages stopped before the pool waits for them
            if stop is not None:
                stop()
            raise
    bar.close()
    missing = [s for s in upstream if s not in done]
    if failed is None and missing:  # a cycle: DVC refuses those before this runs
        raise ValueError(f"stages that never became ready: {missing}")
    return done, failed


class _DvcStages:
    """Runs one stage as a ``dvc repro`` call in a session of its own (a terminal's Ctrl-C
    reaches only the runner, which passes it on once: :meth:`stop`), keeping a copy of each of
    the run's locks (``dvc.lock``, ``rig/dvc.lock``) each time a call ends with it whole."""

    def __init__(self, env: Mapping[str, str], log_dir: Path,
                 locks: Sequence[tuple[Path, Path]] = ((LOCK, GOOD_LOCK),), live: Path = LIVE) -> None:
        self.env, self.log_dir, self.locks, self.live = dict(env), log_dir, list(locks), live
        self._live: dict[subprocess.Popen, str] = {}
        self._guard = threading.Lock()
        self.stopping = False
        for lock, good in self.locks:
            keep_whole(lock, good)
        self._record()

    def _record(self) -> None:
        """Write :data:`LIVE`: this runner and its calls' process groups (each call's pid leads its group)."""
        _write_json(self.live, {"runner": os.getpid(), "calls": {s: p.pid for p, s in self._live.items()}})

    def __call__(self, stage: str) -> StageRun:
        log = self.log_dir / (stage.replace("/", "_") + ".log")
        t0 = time.monotonic()
        with log.open("w") as out:
            with self._guard:
                if self.stopping:
                    return StageRun(130, 0.0)
                proc = subprocess.Popen([sys.executable, "-m", "dvc", "--wait-for-lock", "repro", "--single-item",
                                         stage], stdout=out, stderr=subprocess.STDOUT, env=self.env,
                                        start_new_session=True)
                self._live[proc] = stage
                self._record()
            rc = proc.wait()
            with self._guard:
                self._live.pop(proc, None)
                self._record()
        for lock, good in self.locks:
            keep_whole(lock, good)
        seconds = round(time.monotonic() - t0, 1)
        return StageRun(rc, seconds, skipped=bool(SKIPPED.search(log.read_text(errors="replace"))))

    def stop(self, grace: float = STOP_GRACE_S) -> None:
        """SIGINT to every running call (DVC stops its stage and records nothing of it), then
        SIGKILL to those still running after ``grace`` seconds."""
        with self._guard:
            self.stopping = True
            live = list(self._live)
        by_pid = {p.pid: p for p in live}
        _stop_groups(list(by_pid), grace, wait=lambda pid, timeout: by_pid[pid].wait(timeout=timeout))

    def close(self) -> None:
        """The run has ended with no call running: nothing for a later runner to stop."""
        self.live.unlink(missing_ok=True)


def _stop_groups(groups: list[int], grace: float, wait: Callable[[int, float], object]) -> None:
    """SIGINT to each process group (DVC stops its stage and records nothing of it), then SIGKILL
    to those whose leader has not ended after ``grace`` seconds; ``wait(pid, timeout)`` waits for
    a group's leader (raising ``subprocess.TimeoutExpired``)."""
    for pgid in groups:
        _signal_group(pgid, signal.SIGINT)
    deadline = time.monotonic() + grace
    for pgid in groups:
        try:
            wait(pgid, max(0.0, deadline - time.monotonic()))
        except (subprocess.TimeoutExpired, KeyboardInterrupt):  # too slow, or a second Ctrl-C
            for g in groups:
                _signal_group(g, signal.SIGKILL)
            for g in groups:
                try:
                    wait(g, 10.0)
                except subprocess.TimeoutExpired:
                    pass
            return


def _signal_group(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except ProcessLookupError:  # it has ended
        pass


def _write_json(path: Path, data: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, sort_keys=True))
    tmp.replace(path)


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # a group of another user's: alive, not ours to signal
        return True
    return True


def _wait_group(pgid: int, timeout: float) -> None:
    """Wait until no process of the group ``pgid`` is left (they are not this process's children)."""
    deadline = time.monotonic() + timeout
    while _group_alive(pgid):
        if time.monotonic() >= deadline:
            raise subprocess.TimeoutExpired(f"process group {pgid}", timeout)
        time.sleep(0.1)


def _command(pid: int) -> str:
    """The command line of the process ``pid`` ("" where there is none, or none readable)."""
    import psutil

    try:
        return " ".join(psutil.Process(pid).cmdline())
    except (psutil.Error, OSError):
        return ""


def _is_runner(pid: int) -> bool:
    """Whether ``pid`` is a running ``nanosysid.repro`` (a reused process id is not)."""
    return pid != os.getpid() and "nanosysid.repro" in _command(pid)


def _is_call(pgid: int) -> bool:
    """Whether the group ``pgid`` is still led by a runner's ``dvc repro`` call (a reused id is not)."""
    try:
        return "dvc" in _command(pgid) and os.getpgid(pgid) == pgid
    except OSError:
        return False


class RunnerBusy(RuntimeError):
    """Another runner is running in this repository."""


def stop_orphans(live: Path = LIVE, grace: float = STOP_GRACE_S) -> list[str]:
    """Stop the stage calls a runner killed outright left running (they would go on writing
    outputs and ``dvc.lock`` beside this run, and hold the paths this run's calls need); the
    stages stopped, by name. Raises :class:`RunnerBusy` while that runner is alive."""
    try:
        record = json.loads(live.read_text())
        runner, calls = int(record["runner"]), {str(k): int(v) for k, v in record["calls"].items()}
    except FileNotFoundError:
        return []
    except (ValueError, KeyError, TypeError, AttributeError):  # cut short by the kill: nothing to go on
        live.unlink(missing_ok=True)
        return []
    if _is_runner(runner):
        raise RunnerBusy(f"another `make repro` (process {runner}) is running in this repository: wait for it to "
                         "end, or stop it (Ctrl-C, or kill -INT it)")
    left = {s: g for s, g in calls.items() if _group_alive(g) and _is_call(g)}
    _stop_groups(list(left.values()), grace, wait=_wait_group)
    live.unlink(missing_ok=True)
    return sorted(left)


def _whole(text: str) -> bool:
    """Whether ``text`` is a whole lock file: it parses, holds DVC's ``stages`` mapping and ends
    its last line."""
    import yaml

    # libyaml's loader where there is one: a pipeline's dvc.lock takes the pure-Python one over a
    # second, once a stage ends
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    try:
        data = yaml.load(text, Loader=loader)
    except yaml.YAMLError:
        return False
    return isinstance(data, dict) and isinstance(data.get("stages"), dict) and text.endswith("\n")


def keep_whole(lock: Path = LOCK, good: Path = GOOD_LOCK) -> None:
    """Copy ``lock`` to ``good`` where it is whole (nothing where it is absent or cut short)."""
    try:
        text = lock.read_text()
    except FileNotFoundError:
        return
    if _whole(text):
        good.parent.mkdir(parents=True, exist_ok=True)
        tmp = good.with_name(good.name + ".tmp")
        tmp.write_text(text)
        tmp.replace(good)


def repair_lock(lock: Path = LOCK, good: Path = GOOD_LOCK) -> bool:
    """Put back the last whole copy where ``lock`` is cut short; True where it did."""
    if not lock.exists() or _whole(lock.read_text(errors="replace")) or not good.exists():
        return False
    tmp = lock.with_name(lock.name + ".tmp")
    tmp.write_text(good.read_text())
    tmp.replace(lock)
    return True


RWLOCK = Path(".dvc/tmp/rwlock")  # DVC's record of the paths its running commands read and write


def repair_rwlock(rwlock: Path = RWLOCK) -> bool:
    """Remove DVC's ``rwlock`` where an interruption cut it short (it no longer parses as JSON:
    every later DVC command would refuse to start); once the runner's calls have all ended no
    command of this run holds a path. True where it did."""
    try:
        json.loads(rwlock.read_text(errors="replace"))
        return False
    except FileNotFoundError:
        return False
    except ValueError:
        rwlock.unlink()
        return True


def _interrupt(signum, frame):  # SIGTERM and SIGHUP end the run as Ctrl-C does
    raise KeyboardInterrupt


def _last_times(path: Path) -> dict[str, float]:
    try:
        return {k: float(v) for k, v in json.loads(path.read_text())["stages"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


RECORDED = Path("reports/repro.json")  # the stage times `make readme` recorded (tracked)
RIG_PREFIX = "rig_"  # the rig pipeline's stages (rig/dvc.yaml), on the real flights


def _with_rig(upstream: dict[str, set[str]], params: Path = Path("params-rig.yaml"), *, skip: bool = False
              ) -> dict[str, set[str]]:
    """The stages to run: the rig pipeline's only where its files can be had (the simulated
    world's pipeline needs no data and no network) and not ``skip``; one line says which."""
    rig = {s for s in upstream if (s.partition(":")[2] or s).startswith(RIG_PREFIX)}
    if not rig:
        return upstream
    from omegaconf import OmegaConf

    from nanosysid.rig.fetch import available

    ok, where = False, "--skip-rig" if skip else f"{params} is missing (make params)"
    if params.is_file() and not skip:
        c = OmegaConf.to_container(OmegaConf.load(params), resolve=True)["rig"]
        ok, where = available(c["manifest"], c["paths"]["raw"], local=c["local"],
                              repository=c["upstream"]["repository"], commit=c["upstream"]["commit"])
    if ok:
        print(f"rig pipeline: the real flights from {where}")
        return upstream
    print(f"rig pipeline skipped: {where}")
    return {s: ups - rig for s, ups in upstream.items() if s not in rig}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0].strip("`: "))
    p.add_argument("--jobs", type=int, default=2, help="stages at a time (default 2)")
    p.add_argument("--out", type=Path, default=Path("reports/repro.json"), help="the record of stage times")
    p.add_argument("--pipeline", action="append", choices=PIPELINES,
                   help="a pipeline file whose stages run (default dvc.yaml: the benchmark's, with rig/dvc.yaml); "
                   "given twice, both files' stages in one schedule")
    p.add_argument("--skip-rig", action="store_true", help="leave the rig pipeline's stages out (the simulated "
                   "world's alone, as `make quick` runs it)")
    a = p.parse_args(argv)
    if a.jobs < 1:
        p.error(f"--jobs must be at least 1, got {a.jobs}")
    a.pipeline = a.pipeline or ["dvc.yaml"]
    files = list(dict.fromkeys(f for p in a.pipeline for f in RUNS.get(p, (p,))))
    locks = [lock_of(f) for f in files]
    from dvc.exceptions import DvcException

    # a killed run's calls stopped first: they may be writing dvc.lock, which the graph reads
    orphans, put_back, cleared = [], False, False
    if LOG_DIR.parent.is_dir():  # a DVC repository (else the graph says so below)
        try:
            orphans = stop_orphans()
        except RunnerBusy as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        put_back = any([repair_lock(*lock_of(pipeline)) for pipeline in PIPELINES])
        cleared = repair_rwlock()
        try:
            bad = cachecheck.damaged()
        except DvcException:  # a repository DVC cannot open: the graph below says why, in DVC's words
            bad = []
        for d in bad:
            print(f"damaged DVC cache object, removed: {d}", file=sys.stderr)
        cachecheck.remove(bad)
    if orphans or put_back or cleared:
        print("the last run was killed outright" + (f"; its stages still running were stopped: {', '.join(orphans)}"
                                                   if orphans else "")
              + ("; dvc.lock, cut short, was put back as it was after the last stage that ended" if put_back else "")
              + ("; DVC's .dvc/tmp/rwlock, cut short, was removed" if cleared else "")
              + "; going on from there", file=sys.stderr)
    try:
        upstream = stage_graph(pipeline=files)
    except DvcException as e:  # no repository, a malformed dvc.yaml: DVC's own message, no traceback
        print(f"error: {e}", file=sys.stderr)
        return 2
    upstream = _with_rig(upstream, skip=a.skip_rig)
    if _interrupted:  # its SystemExit went where it could not stop the runner (see _unraisable)
        return 130
    LOG_DIR.mkdir(parents=True, exist_ok=True)
    # this machine's last run where there is one, else the times the repository records
    order = best_order(upstream, _last_times(a.out) or _last_times(RECORDED.with_name(a.out.name.replace(".last", ""))),
                       jobs=a.jobs)
    env = dict(os.environ)
    if a.jobs > 1:
        env["OMP_WAIT_POLICY"] = "PASSIVE"
    stages = _DvcStages(env, LOG_DIR, locks)
    t0 = time.monotonic()
    # an interruption is the runner's to pass on, also where its starter ignores SIGINT (`make repro &`)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGHUP, _interrupt)  # a closed terminal: the stages stopped as on Ctrl-C
    try:
        done, failed = run_graph(upstream, stages, jobs=a.jobs, order=order, stop=stages.stop)
    except KeyboardInterrupt:
        stages.stop()
        stages.close()
        put_back, cleared = any([repair_lock(*pair) for pair in locks]), repair_rwlock()
        print("\ninterrupted: the stages that were running stopped unrecorded"
              + ("; dvc.lock, cut short, was put back as it was after the last stage that ended" if put_back else "")
              + ("; DVC's .dvc/tmp/rwlock, cut short, was removed" if cleared else "")
              + "; `make repro` again goes on from there", file=sys.stderr)
        return 130
    stages.close()
    total = round(time.monotonic() - t0, 1)
    if failed is not None:
        log = LOG_DIR / (failed.replace("/", "_") + ".log")
        tail = deque(log.read_text(errors="replace").splitlines(), maxlen=40)
        print(f"\nstage {failed} failed; the end of its log ({log}):\n" + "\n".join(tail), file=sys.stderr)
        return done[failed].rc or 1
    ran = {s: r.seconds for s, r in done.items() if not r.skipped}
    skipped = sorted(s for s, r in done.items() if r.skipped)
    print(f"{len(ran)} stages ran, {len(skipped)} skipped or cached, in {total:g} s")
    try:
        for line in others_status(a.pipeline):
            print(line)
    except DvcException as e:
        print(f"the other pipelines' status is not known: {e}", file=sys.stderr)
    command = f"python -m nanosysid.repro --jobs {a.jobs}" + "".join(
        f" --pipeline {p}" for p in a.pipeline if a.pipeline != ["dvc.yaml"]) + (" --skip-rig" if a.skip_rig else "")
    write_record(a.out, command,
                 {"jobs": a.jobs, "stages": {s: ran[s] for s in order if s in ran}, "skipped": skipped, "total_s": total})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
