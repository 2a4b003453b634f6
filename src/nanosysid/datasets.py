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
    """Generate the flights of ``cfg.sim`` into ``cfg.sim.out_dir`` (replaced atomically).

    Flights go to ``train/`` and ``test/`` by the split lists, as in the published layout,
    and their trajectory statistics to ``<paths.sim_report>/stats.md``.
    """
    from nanosysid.sim.stats import stats_markdown, trajectory_stats

    s = cfg.sim
    vehicle = Vehicle.from_mapping(cfg.vehicle)
    if s.generator == "flight":
        from nanosysid import sim

        flights = sim.simulate_flights(
            dict(s.runs),
            effects=dict(s.effects),
            seed=int(cfg.seed),
            cfg=sim.SimConfig.from_mapping(OmegaConf.to_container(s.flight, resolve=True)),
            vehicle=vehicle,
            date=str(s.date),
        )
    elif s.generator == "synthetic":
        from nanosysid.synthetic import synthetic_flights

        flights = synthetic_flights(
            flight_names(dict(s.runs), str(s.date)),
            int(s.synthetic.samples),
            vehicle=vehicle,
            substeps=int(s.synthetic.substeps),
            noise=float(s.synthetic.noise),
            seed=int(cfg.seed),
        )
    else:
        raise ConfigError(f"sim.generator: unknown generator {s.generator!r} (known: flight, synthetic)")
    parts = {t: "train" for t in cfg.split.train} | {t: "test" for t in cfg.split.test}
    with atomic_file(Path(cfg.paths.sim_report) / "stats.md") as tmp:
        tmp.write_text(stats_markdown(trajectory_stats(flights)))
    out = Path(s.out_dir)
    with atomic_dir(out) as tmp:
        for f in flights:
            write_flight_csv(f, tmp / parts.get(f.trajectory, "") / f"{f.name}.csv")
    log.info("wrote %d flights to %s", len(flights), out)
    return sorted(out.rglob("*.csv"))
