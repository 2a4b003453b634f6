"""The data sources a pipeline can start from, written in the published CSV layout."""

from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid.config import ConfigError
from nanosysid.dataio import atomic_dir, write_flight_csv
from nanosysid.vehicle import Vehicle

__all__ = ["write_default_dataset", "flight_names"]

log = logging.getLogger(__name__)


def flight_names(runs: dict[str, int], date: str) -> list[str]:
    """``<trajectory>_<date>_run<k>`` for k = 1..runs of each trajectory."""
    return [f"{traj}_{date}_run{k}" for traj, n in runs.items() for k in range(1, n + 1)]


def write_default_dataset(cfg: DictConfig) -> list[Path]:
    """Generate the flights of ``cfg.data`` into ``cfg.data.raw_dir`` (replaced atomically)."""
    data = cfg.data
    if data.source == "synthetic":
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
        raise ConfigError(f"data.source: unknown source {data.source!r} (known: synthetic)")
    out = Path(data.raw_dir)
    with atomic_dir(out) as tmp:
        for f in flights:
            write_flight_csv(f, tmp / f"{f.name}.csv")
    log.info("wrote %d flights to %s", len(flights), out)
    return sorted(out.glob("*.csv"))
