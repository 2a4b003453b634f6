"""Each user-facing path (the Python API's evaluate, the evaluate, identify and discover stages, a
plain ``dvc repro`` of one stage) on an idle machine and beside two busy processes, through the
product's own entry points and settings; the ratio busy / idle of each (a path under half a minute:
the median of three runs each way, since one run's scheduling noise is a good part of its time)."""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from nanosysid import predictors, protocol
from nanosysid.config import load_params

ROOT = Path(__file__).resolve().parents[1]
BUSY = "while True: pass"
SHORT_S, REPEATS = 30.0, 3


def _stage(*args: str) -> None:
    subprocess.run([sys.executable, "-m", *args], cwd=ROOT, check=True, capture_output=True)


def paths(out: Path) -> dict:
    """Each path as a function of no arguments; every output goes under ``out``."""
    cfg = load_params()
    bench = protocol.load(ROOT / cfg.paths.split, horizon=int(cfg.eval.horizon))
    physics = predictors.predictor("physics")
    quick = ["discover.flights_out=false", "discover.sindy=false"]
    return {
        "api_evaluate": lambda: protocol.evaluate(physics, bench.test, horizon=int(cfg.eval.horizon)),
        "stage_evaluate": lambda: _stage("stages.evaluate", "physics", f"paths.eval={out / 'eval'}"),
        "stage_identify": lambda: _stage("stages.identify", f"identify.out_dir={out / 'physics'}"),
        "stage_discover": lambda: _stage("stages.discover", f"discover.out_dir={out / 'discovered'}",
                                         f"discover.report_dir={out / 'discovery'}", *quick),
        "dvc_repro_one_stage": lambda: subprocess.run([str(Path(sys.executable).parent / "dvc"), "repro", "-f",
                                                       "--single-item", "evaluate@physics"], cwd=ROOT, check=True,
                                                      capture_output=True),
    }


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> dict[str, float]:
    figures: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as d:
        todo = paths(Path(d))
        for name, fn in todo.items():
            idle = [timed(fn)]
            repeats = REPEATS if idle[0] < SHORT_S else 1
            idle = statistics.median(idle + [timed(fn) for _ in range(repeats - 1)])
            busy = [subprocess.Popen([sys.executable, "-c", BUSY], env=dict(os.environ)) for _ in range(2)]
            try:
                time.sleep(0.5)
                loaded = statistics.median([timed(fn) for _ in range(repeats)])
            finally:
                for p in busy:
                    p.kill()
                    p.wait()
            figures[f"{name}_idle_s"], figures[f"{name}_busy_s"] = idle, loaded
            figures[f"{name}_busy_over_idle"] = loaded / idle
            print(f"{name:22s} idle {idle:7.2f} s   beside two busy processes {loaded:7.2f} s   "
                  f"{loaded / idle:.2f}x (limit 2x)", flush=True)
    return figures


if __name__ == "__main__":
    main()
