"""The simulate stage's work: the default dataset, simulated, recorded as bags, and as direct CSVs."""

from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

from nanosysid.config import ConfigError
from nanosysid.dataio import atomic_dir, atomic_file, write_flight_csv
from nanosysid.vehicle import Vehicle

__all__ = ["write_default_dataset"]

log = logging.getLogger(__name__)


def write_default_dataset(cfg: DictConfig) -> Path:
    """Simulate the flights of ``cfg.sim`` and record them into ``cfg.sim.out_dir`` (replaced atomically).

    Writes ``bags/<flight>/`` (a ROS 2 bag per flight, as the real rig records), the truth
    beside each bag (``bags/<flight>.truth.parquet`` and ``.truth.json``), and the simulator's
    direct 100 Hz output in the published layout (``csv/train``, ``csv/test``, by the split
    lists); the trajectory statistics go to ``<paths.sim_report>/stats.md``.
    """
    from nanosysid import sim
    from nanosysid.recording.recorder import RecorderConfig, record_flight
    from nanosysid.sim.simulator import flights_from_record, simulate_raw
    from nanosysid.sim.stats import stats_markdown, trajectory_stats

    s = cfg.sim
    vehicle = Vehicle.from_mapping(cfg.vehicle)
    world = sim.World(dict(s.effects))
    sim_cfg = sim.SimConfig.from_mapping(OmegaConf.to_container(s.flight, resolve=True))
    specs = sim.flight_specs(dict(s.runs), str(s.date))
    if not specs:
        raise ConfigError("sim.runs: no flight to simulate")
    raw = simulate_raw(specs, world=world, vehicle=vehicle, cfg=sim_cfg, seed=int(cfg.seed))
    flights = flights_from_record(raw, world=world, vehicle=vehicle, cfg=sim_cfg)
    parts = {t: "train" for t in cfg.split.train} | {t: "test" for t in cfg.split.test}
    topics = OmegaConf.to_container(cfg.recording.topics, resolve=True)
    rec_cfg = RecorderConfig.from_mapping(OmegaConf.to_container(s.recorder, resolve=True))
    out = Path(s.out_dir)
    with atomic_dir(out) as tmp:
        (tmp / "bags").mkdir()
        for i, f in enumerate(tqdm(flights, desc="record", unit="bag", disable=None)):
            record_flight(raw, i, tmp / "bags" / f.name, topics=topics, cfg=rec_cfg, noise=sim_cfg.noise,
                          world=world, vehicle=vehicle, seed=int(cfg.seed))
            write_flight_csv(f, tmp / "csv" / parts.get(f.trajectory, "") / f"{f.name}.csv")
    with atomic_file(Path(cfg.paths.sim_report) / "stats.md") as f:
        f.write_text(stats_markdown(trajectory_stats(flights)))
    log.info("simulated and recorded %d flights into %s", len(flights), out)
    return out
