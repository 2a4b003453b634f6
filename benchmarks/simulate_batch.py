"""Time to simulate one short flight, 16 and 256 in one batch, each flight in its own world.

The worlds (effects, strengths, seeds, user effects) are the campaign's draws; every flight
flies a 5 s chirp. The batch advances all flights together, step by step: the ratios against
one flight, measured in the same run, show how little a flight costs in a batch. The one
flight is the first draw with every simulator effect switched on and a user effect, so that it
runs every code path a batch of many worlds runs.

The product's own settings throughout (its thread count and its compiled step included): once on
an idle machine and once beside a process that keeps one core busy, as on a shared workstation or
CI runner. Each batch size is a compiled step of its own: every size runs once before the timed
runs, so that the times are those of a compiled step, not of compiling it.
"""

from __future__ import annotations

import dataclasses
import functools
import subprocess
import sys
import time

from nanosysid import campaign, sim
from nanosysid.vehicle import Vehicle

SIZES = (1, 16, 256)
DURATION = 5.0  # s


def _times(every, specs, cfg, label: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for n in SIZES:
        t0 = time.perf_counter()
        sim.simulate_flights([every] if n == 1 else specs[:n], cfg=cfg, progress=False)
        out[f"flights_{n}{label}_s"] = time.perf_counter() - t0
    one = out[f"flights_1{label}_s"]
    for n in SIZES[1:]:
        out[f"flights_{n}{label}_over_one"] = out[f"flights_{n}{label}_s"] / one
    return out


def main() -> dict[str, float]:
    cfg = sim.SimConfig.from_mapping({"trajectories": {"chirp": {"duration": DURATION}}})
    draws = campaign.draw(max(SIZES), seed=0)
    vehicle = Vehicle()
    specs = [sim.FlightSpec(trajectory="chirp", run=1, effects=w.effects, seed=w.seed, extra_wrench=w.extra_wrench(vehicle),
                            name=f"chirp_w{w.index}_run1") for w in draws]
    every = dataclasses.replace(specs[0], effects={e: 1.0 for e in sim.EFFECTS},
                                extra_wrench=functools.partial(campaign.thrust_sag, s=1.0, k_f=vehicle.k_f))
    for n in SIZES:  # warm-up: imports, first allocations, each size's compiled step
        sim.simulate_flights([every] if n == 1 else specs[:n], cfg=cfg, progress=False)
    out = _times(every, specs, cfg, "")
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])  # one core taken
    try:
        out.update(_times(every, specs, cfg, "_busy"))
    finally:
        busy.kill()
        busy.wait()
    for label, what in (("", "idle"), ("_busy", "one core busy")):
        one = out[f"flights_1{label}_s"]
        for n in SIZES:
            print(f"{what:>13}: {n:4d} flights of {DURATION:g} s in one batch: {out[f'flights_{n}{label}_s']:6.2f} s "
                  f"({out[f'flights_{n}{label}_s'] / one:.2f}x one flight)")
    return out


if __name__ == "__main__":
    main()
