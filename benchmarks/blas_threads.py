"""The window track's rate map fitted on two training flights (``nanosysid.window.fit_rate_map``,
numpy's matrix products over every window) on one OpenBLAS thread (the product's,
``OPENBLAS_NUM_THREADS=1``) against two, each alone and beside a second copy of itself (as
``make repro`` runs two stages on two cores), in the same run.

Each fit runs in a process of its own, pinned as a stage is (``nanosysid.numerics``), the thread
count set before numpy is loaded; the base is holding the rate (no predictor's time in it); two
flights keep the slow case, two threads side by side, within a minute.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIT = """
import os, sys
from nanosysid import numerics
numerics.pin()
os.environ["OPENBLAS_NUM_THREADS"] = sys.argv[1]  # after the pin, before numpy is loaded
import time
import numpy as np
from nanosysid import dynamics, protocol
from nanosysid.config import load_params
from nanosysid.vehicle import Vehicle
cfg = load_params()
train = protocol.load(cfg.paths.split).train[:2]
v = Vehicle()
torque_map = dynamics.mixer_matrix(k_f=v.k_f, k_m=v.k_m, arm=v.arm).numpy()[1:]
held = lambda y0, u: np.repeat(np.asarray(y0)[:, None], np.shape(u)[1], axis=1)
from nanosysid.window import fit_rate_map
t0 = time.perf_counter()
fit_rate_map(train, base=held, torque_map=torque_map, inertia=v.inertia)
print(time.perf_counter() - t0)
"""


def _fits(threads: int, copies: int) -> float:
    """The slowest of ``copies`` fits started together, each on ``threads`` OpenBLAS threads (s)."""
    procs = [subprocess.Popen([sys.executable, "-c", FIT, str(threads)], cwd=ROOT, stdout=subprocess.PIPE,
                              text=True, env=dict(os.environ)) for _ in range(copies)]
    out = [p.communicate()[0] for p in procs]
    if any(p.returncode for p in procs):
        raise RuntimeError("a fit failed")
    return max(float(o.strip().splitlines()[-1]) for o in out)


def main() -> dict[str, float]:
    t0 = time.perf_counter()
    figures = {}
    for threads in (1, 2):
        key = "one_thread" if threads == 1 else "two_threads"
        figures[f"{key}_alone_s"] = _fits(threads, 1)
        figures[f"{key}_side_by_side_s"] = _fits(threads, 2)
    for how in ("alone", "side_by_side"):
        two, one = figures[f"two_threads_{how}_s"], figures[f"one_thread_{how}_s"]
        figures[f"two_threads_{how}_over_one"] = two / one
    for k, v in figures.items():
        print(f"{k}: {v:.3g}")
    print(f"({time.perf_counter() - t0:.0f} s in all)")
    return figures


if __name__ == "__main__":
    main()
