"""Time of discovery's held-out rollouts (the base and generic-term choices' SimErr on the
training flights, ten folds) with each fold's windows of every flight rolled out together (the
product's), against one rollout per flight and fold, in the same run.

The default dataset's training flights, a window every 5 samples, dealt to 10 folds by 2 s
blocks, each fold rolled out by its own model (the nominal vehicle with induced drag); both ways
give the same SimErr, which the script checks.
"""

from __future__ import annotations

import time

import numpy as np

from nanosysid import protocol
from nanosysid.config import load_params
from nanosysid.discover.assemble import STRIDE, heldout_simerr
from nanosysid.discover.model import AugmentedPredictor, AugmentedStep
from nanosysid.metrics import QUANTITIES
from nanosysid.vehicle import Vehicle

FOLDS, BLOCK = 10, 200  # folds, and samples per block (2 s at 100 Hz)


def main() -> dict[str, float]:
    cfg = load_params()
    flights = protocol.load(cfg.paths.split).train
    H = int(cfg.eval.horizon)
    starts = []
    for f in flights:
        s = np.arange(0, len(f) - H, STRIDE)
        starts.append([s[(s // BLOCK) % FOLDS == k] for k in range(FOLDS)])
    models = [AugmentedPredictor(AugmentedStep(Vehicle(), ["induced_drag"], [2e-6 * (1 + 0.01 * k), 1.5e-6]))
              for k in range(FOLDS)]
    t0 = time.perf_counter()
    batched = heldout_simerr(models, flights, starts, H, int(cfg.eval.batch_size))
    t_batched = time.perf_counter() - t0
    t0 = time.perf_counter()
    sums, n = {q: 0.0 for q in QUANTITIES}, 0
    for f, s in zip(flights, starts):  # the reference: one rollout per flight and fold
        for k, predict in enumerate(models):
            if len(s[k]):
                one = heldout_simerr([predict], [f], [[s[k]]], H, int(cfg.eval.batch_size))
                for q in QUANTITIES:
                    sums[q] += one[q] * len(s[k])
                n += len(s[k])
    t_loop = time.perf_counter() - t0
    same = all(abs(sums[q] / n - batched[q]) <= 1e-9 * batched[q] for q in QUANTITIES)
    windows = sum(len(x) for s in starts for x in s)
    print(f"{len(flights)} training flights, {windows} held-out windows, {FOLDS} folds")
    print(f"each fold's windows together: {t_batched:.1f} s; one rollout per flight and fold: {t_loop:.1f} s "
          f"({t_loop / t_batched:.1f}x); same SimErr: {same}")
    return {"windows": windows, "batched_s": t_batched, "per_flight_s": t_loop, "speedup": t_loop / t_batched,
            "same_simerr": same}


if __name__ == "__main__":
    main()
