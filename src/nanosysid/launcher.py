"""One way to fan work out, in two places: processes on this machine, or array jobs on a SLURM
cluster through submitit.

Example::

    from nanosysid import launcher
    spec = launcher.Launcher.from_mapping({"kind": "local", "workers": 2})
    squares = launcher.map_tasks(pow, [(2, 2), (3, 2)], spec)   # [4, 9], in the tasks' order

A task is a picklable function and its arguments; the results come back in the tasks' order
whatever the number of workers and wherever they ran, so the same tasks give the same results
(every task pins its own thread count: a result never depends on how many tasks share a machine).
On a cluster, every node needs the shared ``folder`` (submitit writes the pickled tasks, the
logs and the results there) and the same virtual environment at the same path.
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from nanosysid.errors import ConfigError, JobError
from nanosysid.numerics import threads as torch_threads

__all__ = ["Launcher", "KINDS", "even_parts", "map_tasks", "slurm_executor"]

KINDS = ("local", "slurm")


@dataclass(frozen=True)
class Launcher:
    """Where tasks run (``conf/launcher/``).

    Attributes:
        kind: ``"local"`` (processes on this machine) or ``"slurm"`` (submitit array jobs).
        workers: local: processes side by side (None: this machine's cores); slurm: array tasks
            running at once.
        threads: torch threads of each task.
        partition, time_min, mem_gb, cpus_per_task: slurm: the job's partition, time limit
            (minutes), memory (GB) and cores.
        folder: slurm: a folder every node sees, for submitit's pickles, logs and results.
        cluster: slurm: submitit's cluster; ``"slurm"`` on a cluster, ``"local"`` or ``"debug"``
            (submitit's stand-ins, on this machine) to try the path without one.
    """

    kind: str = "local"
    workers: int | None = None
    threads: int = 1
    partition: str | None = None
    time_min: int = 60
    mem_gb: float = 8.0
    cpus_per_task: int = 1
    folder: str = ".submitit"
    cluster: str = "slurm"

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any] | None, where: str = "launcher") -> "Launcher":
        """A launcher from its config block; one clear error for an unknown key or a bad value."""
        d = dict(d or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        spec = cls(**d)
        if spec.kind not in KINDS:
            raise ConfigError(f"{where}.kind: {spec.kind!r} is not one of {', '.join(KINDS)}")
        if spec.workers is not None and (not isinstance(spec.workers, int) or spec.workers < 1):
            raise ConfigError(f"{where}.workers: {spec.workers!r} is not a positive whole number (or null: every core)")
        for name in ("threads", "time_min", "cpus_per_task"):
            if not isinstance(getattr(spec, name), int) or getattr(spec, name) < 1:
                raise ConfigError(f"{where}.{name}: {getattr(spec, name)!r} is not a positive whole number")
        if spec.cluster not in ("slurm", "local", "debug"):
            raise ConfigError(f"{where}.cluster: {spec.cluster!r} is not one of slurm, local, debug")
        return spec

    @property
    def processes(self) -> int:
        """Local processes side by side."""
        return self.workers or os.cpu_count() or 1

    @property
    def slots(self) -> int:
        """Tasks running at once: the local processes, or the cluster's array tasks."""
        return self.processes if self.kind == "local" else self.workers or 64


def _pinned(fn: Callable[..., Any], count: int, args: tuple) -> Any:
    from threadpoolctl import threadpool_limits

    # numpy's BLAS too: beside the other workers its idle threads spin for nothing (a campaign
    # task of 15 worlds spent 9 % more core time with two of them, for the same bytes)
    with torch_threads(count), threadpool_limits(limits=count, user_api="blas"):
        return fn(*args)


def slurm_executor(spec: Launcher, *, name: str = "nanosysid"):
    """The submitit executor of a ``slurm`` launcher: array jobs with its partition, time and
    memory, at most ``workers`` running at once."""
    try:
        import submitit
    except ImportError:  # pragma: no cover - submitit is in requirements.txt
        raise ConfigError("launcher=slurm needs submitit: pip install -c constraints.txt submitit") from None
    if spec.cluster == "slurm" and shutil.which("sbatch") is None:
        raise ConfigError("launcher=slurm: no SLURM cluster here (no sbatch on the PATH); run from a login node of "
                          "the cluster, choose launcher=local, or set launcher.cluster=local to try the path on "
                          "this machine")
    Path(spec.folder).mkdir(parents=True, exist_ok=True)
    ex = submitit.AutoExecutor(folder=str(Path(spec.folder) / "%j"), cluster=spec.cluster)
    params: dict[str, Any] = {"name": name, "timeout_min": spec.time_min, "mem_gb": spec.mem_gb,
                              "cpus_per_task": spec.cpus_per_task, "slurm_array_parallelism": spec.slots}
    if spec.partition:
        params["slurm_partition"] = spec.partition
    ex.update_parameters(**params)
    return ex


def _result(job, spec: Launcher) -> Any:
    """A cluster job's result; a task that raised a user's mistake raises it here, and a job the
    cluster failed (killed, out of time or memory) is one line naming the job and its log."""
    from submitit.core.utils import FailedJobError, UncompletedJobError

    try:
        return job.result()
    except (FailedJobError, UncompletedJobError) as e:
        lines = [line for line in str(e).splitlines() if line.strip()]
        last = next((line for line in reversed(lines) if "Error" in line), lines[-1] if lines else type(e).__name__)
        raise JobError(f"launcher=slurm: job {job.job_id} failed ({last.strip()}); its log is in "
                          f"{Path(spec.folder) / str(job.job_id).split('_')[0]}") from None


def even_parts(n: int, size: int, slots: int) -> list[range]:
    """``range(n)`` cut into consecutive parts of at most ``size``, their count the smallest
    multiple of ``slots`` that allows (at most ``n``), their sizes differing by at most one.

    Parts of exactly ``size`` leave a short last part, and a count that is not a multiple of
    the slots leaves slots idle while the others run one part more: 200 worlds in parts of 15
    on two workers are 14 parts, one of 5, and one worker judges 105 worlds while the other
    judges 95; even parts give each worker 100.
    """
    if n <= 0:
        return []
    count = -(-n // size)
    count = min(n, -(-count // slots) * slots)
    small, extra = divmod(n, count)
    ends = list(itertools.accumulate(small + (i < extra) for i in range(count)))
    return [range(a, b) for a, b in zip([0, *ends[:-1]], ends)]


def map_tasks(fn: Callable[..., Any], tasks: Sequence[tuple], spec: Launcher | None = None, *,
              progress: bool = False, desc: str = "tasks", name: str = "nanosysid") -> list[Any]:
    """``[fn(*t) for t in tasks]``, run where ``spec`` says; results in the tasks' order."""
    from tqdm.auto import tqdm

    spec = spec or Launcher()
    tasks = [tuple(t) for t in tasks]
    fns, threads = [fn] * len(tasks), [spec.threads] * len(tasks)
    pool = None
    if spec.kind == "slurm":
        jobs = slurm_executor(spec, name=name).map_array(_pinned, fns, threads, tasks)
        results = (_result(job, spec) for job in jobs)
    elif spec.processes == 1 or len(tasks) <= 1:
        results = map(_pinned, fns, threads, tasks)
    else:
        # spawned, not forked: a fork of a process that has run torch's thread pool can hang
        pool = ProcessPoolExecutor(min(spec.processes, len(tasks)), mp_context=multiprocessing.get_context("spawn"))
        results = pool.map(_pinned, fns, threads, tasks)
    try:
        return list(tqdm(results, total=len(tasks), desc=desc, disable=not progress))
    finally:
        if pool is not None:
            pool.shutdown()
