"""The data sources a pipeline can start from, written in the published CSV layout."""

from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from nanosysid.config import ConfigError
from nanosysid.dataio import atomic_dir, atomic_file, write_flight_csv
from nanosysid.vehicle import Vehicle

__all__ = ["write_default_dataset", "flight_names"]

log = logging.getLogger(__name__)


def flight_names(runs: dict[str, int], date: str) -> list[str]:
    """``<trajectory>_<date>_run<k>`` for k = 1..runs of each trajectory."""
    return [f"{traj}_{date}_run{k}" for traj, n in runs.items() for k in range(1, n + 1)]


def write_default_dataset(cfg: DictConfig) -> list[Path]:
    """Generate the flights of ``cfg.data`` into ``cfg.data.raw_dir`` (replaced atomically).

    Simulated flights go to ``train/`` and ``test/`` by the split lists, as in the published
    layout, and their trajectory statistics to ``<paths.sim_report>/stats.md``.
    """
    from nanosysid.sim.stats import stats_markdown, trajectory_stats

    data = cfg.data
    parts: dict[str, str] = {}
    if data.source == "sim":
        from nanosysid import sim

        flights = sim.simulate_flights(
            dict(data.runs),
            effects=dict(data.effects),
            seed=int(cfg.seed),
            cfg=sim.SimConfig.from_mapping(OmegaConf.to_container(data.sim, resolve=True)),
            vehicle=Vehicle.from_mapping(cfg.vehicle),
            date=str(data.date),
        )
        parts = {t: "train" for t in cfg.split.train} | {t: "test" for t in cfg.split.test}
    elif data.source == "synthetic":
        from nanosysid.synthetic import synthetic_flights

        flights = synthetic_flights(
            flight_names(dict(data.runs), str(data.date)),
            int(data.samples),
            vehicle=Vehicle.from_mapping(cfg.vehicle),
            substeps=int(data.substeps),
            noise=float(data.noise),
            seed=int(cfg.seed),
        )
    else:
        raise ConfigError(f"data.source: unknown source {data.source!r} (known: sim, synthetic)")
    with atomic_file(Path(cfg.paths.sim_report) / "stats.md") as tmp:
        tmp.write_text(stats_markdown(trajectory_stats(flights)))
    out = Path(data.raw_dir)
    with atomic_dir(out) as tmp:
        for f in flights:
            write_flight_csv(f, tmp / parts.get(f.trajectory, "") / f"{f.name}.csv")
    log.info("wrote %d flights to %s", len(flights), out)
    return sorted(out.rglob("*.csv"))
