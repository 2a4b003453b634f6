"""simulate: the default dataset, simulated, recorded as ROS 2 bags (as the real rig records)
and written directly as flight CSVs."""

import logging
from pathlib import Path

from omegaconf import DictConfig
from tqdm.auto import tqdm

from nanosysid import sim
from nanosysid.bags.recorder import RecorderConfig, record_flight
from nanosysid.dataio import atomic_dir, write_flight_csv
from nanosysid.errors import ConfigError
from nanosysid.sim.envelope import check_flown
from nanosysid.sim.simulator import flights_from_record, simulate_raw
from stages.common import plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.simulate")


def main(cfg: DictConfig) -> None:
    """Simulate the flights of ``cfg.sim`` and record them into ``cfg.sim.out_dir`` (replaced atomically).

    Writes ``bags/<flight>/`` (a ROS 2 bag per flight), the truth beside each bag
    (``bags/<flight>.truth.parquet`` and ``.truth.json``), and the simulator's direct 100 Hz
    output in the published layout (``csv/<flight>.csv``; the split stage assigns them to
    train and test).
    """
    s = cfg.sim
    vehicle = vehicle_of(cfg)
    sim_cfg = sim.SimConfig.from_mapping(plain(s.flight))
    specs = sim.flight_specs(dict(s.runs), dict(s.effects), int(cfg.seed))
    if not specs:
        raise ConfigError("sim.runs: no flight to simulate")
    raw = simulate_raw(specs, vehicle=vehicle, cfg=sim_cfg, date=str(s.date))
    flights = flights_from_record(raw, vehicle=vehicle, cfg=sim_cfg)
    # the effects above their realistic magnitude (1) are the likely cause
    strong = ", ".join(f"{k} {v:g}" for k, v in s.effects.items() if v > 1)
    check_flown(flights, f"sim.effects ({strong})" if strong else "sim.effects or sim.flight.gains")
    topics = plain(cfg.preprocess.topics)
    rec_cfg = RecorderConfig.from_mapping(plain(s.recorder))
    out = Path(s.out_dir)
    with atomic_dir(out) as tmp:
        (tmp / "bags").mkdir()
        for i, f in enumerate(tqdm(flights, desc="record", unit="bag", disable=None)):
            record_flight(raw, i, tmp / "bags" / f.name, topics=topics, cfg=rec_cfg, noise=sim_cfg.noise,
                          vehicle=vehicle)
            write_flight_csv(f, tmp / "csv" / f"{f.name}.csv")
    log.info("simulated and recorded %d flights into %s", len(flights), out)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
