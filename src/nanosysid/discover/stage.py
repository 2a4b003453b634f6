"""The discover stage's work: the workflow on the configured split, the augmented model and its report."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from nanosysid import benchmark, discover
from nanosysid.dataio import atomic_dir
from nanosysid.discover.model import save_model
from nanosysid.discover.report import write_report
from nanosysid.models import build_from_config
from nanosysid.vehicle import Vehicle

__all__ = ["discover_from_config"]

log = logging.getLogger(__name__)


def discover_from_config(cfg: DictConfig) -> discover.DiscoveryResult:
    """Run :func:`nanosysid.discover.run` on ``paths.split``; write ``<discover.out_dir>/model.json``
    and ``<discover.report_dir>/`` (report, result, figures)."""
    dc = cfg.discover
    oracle = None
    if dc.oracle is not None:
        oracle = build_from_config(OmegaConf.to_container(dc.oracle, resolve=True))
    H = int(cfg.eval.horizon)
    bench = benchmark.load(cfg.paths.split, horizon=H)
    delays = np.arange(1, int(round(float(dc.delay_max) / float(dc.delay_step))) + 1) * float(dc.delay_step)
    result = discover.run(bench.train, bench.test, vehicle=Vehicle.from_mapping(OmegaConf.to_container(cfg.vehicle)),
                          threshold=float(dc.threshold), delays=tuple(delays), window=int(dc.savgol_window),
                          order=int(dc.savgol_order), horizon=H, oracle=oracle, batch_size=int(cfg.eval.batch_size))
    step = result.model.step
    effects, k = {}, 0
    for name in step.effects:
        n = len(discover.CANDIDATES[name].params)
        effects[name] = {"params": discover.CANDIDATES[name].params, "coefficients": step.theta[k:k + n].tolist()}
        k += n
    save_model(Path(dc.out_dir) / "model.json", result.vehicle, effects, result.model.delay,
               dt=step.dt, substeps=step.substeps)
    with atomic_dir(Path(dc.report_dir)) as tmp:
        write_report(result, tmp)
    log.info("discover: %s; SimErr p %.3g -> %.3g, v %.3g -> %.3g, R %.3g -> %.3g, w %.3g -> %.3g", result.name,
             *(x for q in "pvRw" for x in (result.before.simerr[q], result.after.simerr[q])))
    return result
