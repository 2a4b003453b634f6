"""Time to simulate the default dataset (15 flights, default world) as one batch.

Also times one Melon flight alone, in the same run: the batch advances all flights together,
so 15 flights cost little more than the longest one.
"""

from __future__ import annotations

import time

from nanosysid import sim

RUNS = {"square": 4, "random": 4, "chirp": 4, "melon": 3}


def main() -> dict[str, float]:
    t0 = time.perf_counter()
    sim.simulate_flight("melon", 1)
    t_one = time.perf_counter() - t0
    t0 = time.perf_counter()
    flights = sim.simulate_flights(RUNS, progress=False)
    t_all = time.perf_counter() - t0
    samples = sum(len(f) for f in flights)
    # one at a time, each flight would cost in proportion to its length
    sequential = t_one * samples / len(flights[-1])
    print(f"one Melon flight (65 s of flight):      {t_one:.1f} s")
    print(f"all {len(flights)} flights as one batch ({samples} samples): {t_all:.1f} s "
          f"({t_all / t_one:.2f}x one flight; one at a time about {sequential:.0f} s)")
    return {"one_flight_s": t_one, "batch_s": t_all, "flights": len(flights), "batch_over_one": t_all / t_one,
            "sequential_estimate_s": sequential}


if __name__ == "__main__":
    main()
