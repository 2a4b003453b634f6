"""The time of each pipeline stage of one DVC command, and the record ``make repro`` writes.

``make repro`` runs the stages side by side (:mod:`nanosysid.repro`) and writes this module's
record. ``python -m nanosysid.report.runtimes --out reports/repro.json -- dvc repro`` times a
plain DVC command in the same record, one stage at a time: it runs the command,
passes its output through, and times each stage from DVC's own lines (``Running stage 'X'``
to the lock file's update). When the command succeeds it writes the record: the machine, each
stage that ran and its seconds, the stages DVC skipped or restored from its run cache, and the
total. The README's run-times section shows it beside ``make bench``'s record
(:func:`nanosysid.report.readme.bench_section`).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterable, TextIO

from nanosysid import numerics
from nanosysid.dataio import atomic_file

__all__ = ["FORMAT", "SKIPPED", "machine", "stage_times", "write_record", "main"]

FORMAT = "nanosysid-repro-1"

_RUNNING = re.compile(r"Running stage '([^']+)'")
# DVC's line for a stage it did not run: unchanged, or restored from its run cache
SKIPPED = re.compile(r"Stage '([^']+)' (didn't change, skipping|is cached - skipping run)")
_DONE = re.compile(r"Updating lock file")


def machine() -> dict[str, object]:
    """The machine a time was measured on: CPU model, cores, the pinned thread count, torch and Python."""
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "threads": int(numerics.THREADS), "torch": torch.__version__,
            "python": platform.python_version()}


def stage_times(lines: Iterable[str], clock=time.monotonic, echo: TextIO | None = None) -> dict[str, object]:
    """Each stage's seconds from DVC's output ``lines`` (read as they come, each echoed to
    ``echo``): from its ``Running stage`` line to its lock-file update (or the next stage).
    Returns ``{"stages": {name: s}, "skipped": [names], "total_s": s}``."""
    start = clock()
    times: dict[str, float] = {}
    skipped: list[str] = []
    current, since = None, start
    for line in lines:
        if echo is not None:
            echo.write(line)
            echo.flush()
        now = clock()
        if (m := _RUNNING.search(line)) or _DONE.search(line) or SKIPPED.search(line):
            if current is not None:
                times[current] = round(now - since, 1)
                current = None
        if m:
            current, since = m.group(1), now
        elif (s := SKIPPED.search(line)):
            skipped.append(s.group(1))
    end = clock()
    if current is not None:
        times[current] = round(end - since, 1)
    return {"stages": times, "skipped": skipped, "total_s": round(end - start, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("reports/repro.json"))
    p.add_argument("command", nargs=argparse.REMAINDER, help="the command after --, e.g. dvc repro")
    a = p.parse_args(argv)
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not cmd:
        p.error("give the command to time after --")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    record = stage_times(proc.stdout, echo=sys.stdout)
    rc = proc.wait()
    if rc != 0:
        return rc
    write_record(a.out, " ".join(Path(cmd[0]).name.split() + cmd[1:]), record)
    return 0


def write_record(out: Path, command: str, record: dict[str, object]) -> None:
    """Write the record (``stages``, ``skipped``, ``total_s`` and what else ``record`` holds) with
    the machine and the command, when a stage ran: the record is the last run that ran one."""
    if not record["stages"]:
        return
    payload = {"format": FORMAT, "machine": machine(), "command": command, **record}
    with atomic_file(out, replace=True) as tmp:
        tmp.write_text(json.dumps(payload, indent=1) + "\n")
    print(f"{out}: {len(record['stages'])} stages timed, {record['total_s']:g} s")


if __name__ == "__main__":
    raise SystemExit(main())
