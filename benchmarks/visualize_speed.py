"""Time of writing the rerun recordings of the test flights (every model's rollouts), against
the time of only predicting them, in the same run."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from omegaconf import OmegaConf

from nanosysid import protocol
from nanosysid.config import load_params
from nanosysid.predictors import build_from_options
from nanosysid.viz.rerun import write_recording


def main() -> dict[str, float]:
    cfg = load_params()
    H = int(cfg.eval.horizon)
    t0 = time.perf_counter()
    bench = protocol.load(cfg.paths.split, horizon=H)
    predictors = {n: build_from_options(OmegaConf.to_container(m, resolve=True)) for n, m in cfg.models.items()}
    t_load = time.perf_counter() - t0
    t_pred = t_write = 0.0
    with tempfile.TemporaryDirectory() as d:
        for flight in bench.test:
            t0 = time.perf_counter()
            rollouts = {name: protocol.predictions(p, flight, horizon=H) for name, p in predictors.items()}
            t_pred += time.perf_counter() - t0
            t0 = time.perf_counter()
            write_recording(flight, rollouts, Path(d) / f"{flight.name}.rrd", stride=int(cfg.visualize.stride))
            t_write += time.perf_counter() - t0
            size = (Path(d) / f"{flight.name}.rrd").stat().st_size
    print(f"{len(bench.test)} test flights, {len(predictors)} models")
    print(f"load flights and models: {t_load:.2f} s")
    print(f"predict every window:    {t_pred:.2f} s")
    print(f"write recordings:        {t_write:.2f} s ({size / 1e6:.1f} MB each; {t_write / t_pred:.2f}x the prediction)")
    print(f"total:                   {t_load + t_pred + t_write:.2f} s (limit 30 s)")
    return {"load_s": t_load, "predict_s": t_pred, "write_s": t_write, "write_over_predict": t_write / t_pred,
            "total_s": t_load + t_pred + t_write}


if __name__ == "__main__":
    main()
