"""Speed of `protocol.evaluate` on a test set the size of the paper's, against a plain loop.

The paper's test set (three Melon runs, 19,497 samples) gives about 19,350 windows of
H = 50. The reference is the obvious implementation: a Python loop over windows and over
the 50 steps, one sample at a time, computing the same metrics. It runs on a subset of the
windows and is scaled to the full count (its cost is linear in the number of windows); both
give the same MAE on that subset, which the script checks.
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from nanosysid import predictors, protocol, so3, synthetic

H = 50
SUBSET = 200  # windows for the loop reference


def loop_reference(step, flight, n_windows):
    """MAE curves of `n_windows` windows, computed window by window, step by step."""
    sums = {k: np.zeros(H) for k in ("p", "v", "R", "w")}
    for t in range(n_windows):
        y = torch.from_numpy(flight.y[t])
        for h in range(H):
            y = step(y, torch.from_numpy(flight.u[t + h]))
            pred, true = y.numpy(), flight.y[t + h + 1]
            sums["p"][h] += math.dist(pred[0:3], true[0:3])
            sums["v"][h] += math.dist(pred[3:6], true[3:6])
            sums["w"][h] += math.dist(pred[10:13], true[10:13])
            rel = so3.quat_mul(so3.quat_conj(torch.from_numpy(true[6:10])), torch.from_numpy(pred[6:10])).numpy()
            sums["R"][h] += 2 * math.atan2(math.hypot(*rel[:3]), abs(rel[3]))
    return {k: v / n_windows for k, v in sums.items()}


def main() -> dict[str, float]:
    names = [f"melon_bench_run{k}" for k in (1, 2, 3)]
    flights = synthetic.synthetic_flights(names, 6499, substeps=1, noise=1e-3, seed=0)
    predict = predictors.predictor("physics")
    n = sum(len(f) - H for f in flights)

    protocol.evaluate(predict, flights[:1], horizon=H)  # warm-up (allocator, kernels)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        scores = protocol.evaluate(predict, flights, horizon=H)
        times.append(time.perf_counter() - t0)
    t_vec = min(times)

    t0 = time.perf_counter()
    ref = loop_reference(predict.step, flights[0], SUBSET)
    t_loop = (time.perf_counter() - t0) * n / SUBSET

    sub = protocol.Flight(flights[0].name, flights[0].t[: SUBSET + H], flights[0].u[: SUBSET + H], flights[0].y[: SUBSET + H])
    check = protocol.evaluate(predict, [sub], horizon=H)
    same = all(np.allclose(check.mae[k], ref[k], rtol=1e-9, atol=1e-12) for k in ref)

    print(f"windows: {n} x {H} steps (3 flights of {len(flights[0])} samples)")
    print(f"protocol.evaluate(physics): {t_vec:.3f} s (best of 3)")
    print(f"per-window, per-step loop:   {t_loop:.1f} s (measured on {SUBSET} windows, scaled to {n})")
    print(f"speed-up: {t_loop / t_vec:.0f}x; same MAE on the subset: {same}")
    print(f"SimErr p {scores.simerr['p']:.4f} m, v {scores.simerr['v']:.4f} m/s")
    return {"windows": n, "evaluate_s": t_vec, "loop_s": t_loop, "speedup": t_loop / t_vec, "same_mae": same}


if __name__ == "__main__":
    main()
