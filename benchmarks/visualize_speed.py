"""Time of the visualize stage (the rerun recordings of the test flights, from the rollouts the
evaluate stage kept), against the time of rolling every model out again on them, in the same run."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from omegaconf import OmegaConf

from nanosysid import protocol
from nanosysid.config import load_params
from nanosysid.predictors import build_from_options
from stages import visualize


def main() -> dict[str, float]:
    with tempfile.TemporaryDirectory() as d:
        cfg = load_params([f"visualize.out_dir={Path(d) / 'rerun'}"])
        t0 = time.perf_counter()
        written = visualize.main(cfg)
        t_stage = time.perf_counter() - t0
        size = max(p.stat().st_size for p in written)
    H = int(cfg.eval.horizon)
    bench = protocol.load(cfg.paths.split, horizon=H)
    t0 = time.perf_counter()
    for m in cfg.models.values():
        p = build_from_options(OmegaConf.to_container(m, resolve=True))
        for flight in bench.test:
            protocol.predictions(p, flight, horizon=H)
    t_pred = time.perf_counter() - t0
    print(f"{len(bench.test)} test flights, {len(cfg.models)} models")
    print(f"visualize stage:              {t_stage:.2f} s (recordings up to {size / 1e6:.1f} MB)")
    print(f"rolling every model out again: {t_pred:.2f} s (what the stage would add without the kept rollouts)")
    print(f"stage / roll-out:              {t_stage / t_pred:.3f}x")
    return {"stage_s": t_stage, "predict_s": t_pred, "stage_over_predict": t_stage / t_pred}


if __name__ == "__main__":
    main()
