"""Time to simulate the default dataset (15 flights and the 2 yaw sweeps, default world) as one batch, with the step compiled (the product's setting) against the same step run eagerly.

The compiled batch is timed twice in the same process: the first run includes building the
step (inductor's compile, or reading its disk cache when an earlier run compiled it), the second
is what every later batch of this size and world costs. The eager step (``compile: false``) is
the reference, run once.
"""

from __future__ import annotations

import dataclasses
import time

from nanosysid import sim
from nanosysid.settings import defaults

RUNS = defaults("sim/default.yaml", "runs")


def _time(cfg: sim.SimConfig) -> tuple[float, int]:
    t0 = time.perf_counter()
    flights = sim.simulate_flights(RUNS, cfg=cfg, progress=False)
    return time.perf_counter() - t0, len(flights)


def main() -> dict[str, float]:
    cfg = sim.SimConfig()
    first, n = _time(cfg)
    again, _ = _time(cfg)
    eager, _ = _time(dataclasses.replace(cfg, compile=False))
    print(f"{n} flights, compiled step: {first:.1f} s the first time (with the compile), {again:.1f} s again")
    print(f"{n} flights, eager step:    {eager:.1f} s ({eager / again:.1f}x the compiled one)")
    return {"flights": n, "compiled_first_s": first, "compiled_s": again, "eager_s": eager,
            "eager_over_compiled": eager / again}


if __name__ == "__main__":
    main()
