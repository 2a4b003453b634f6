"""quality: the processed flights checked: the simulated ones against the simulator's truth and
direct output; the rig's (``preprocess.format: logs``) by the rules their logs needed and their
acceleration frame against the authors' processed values."""

import json
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from nanosysid.dataio import atomic_file, json_text
from nanosysid.report import rig
from nanosysid.report.quality import quality_report
from stages.common import plain, run_stage, vehicle_of


def main(cfg: DictConfig) -> None:
    r = cfg.preprocess
    if r.format == "logs":
        return rig_quality(cfg)
    quality_report(
        r.flights_dir,
        r.bags_dir,
        Path(cfg.sim.out_dir) / "csv",
        Path(r.report_dir) / "sync.json",
        r.report_dir,
        vehicle=vehicle_of(cfg),
        test_trajectories=list(cfg.split.test),
        horizon=int(cfg.eval.horizon),
        lag_tolerance=float(r.sync.lag_tolerance),
        rotor_delay=float(cfg.data.rotor_delay or 0.0),
    )


def rig_quality(cfg: DictConfig) -> None:
    """``<preprocess.report_dir>/quality.md`` and ``quality.json`` for the rig's flights."""
    r = cfg.preprocess
    extract, report_dir, raw = Path(r.extract_dir), Path(r.report_dir), Path(cfg.rig.paths.raw)
    logs = json.loads((extract / "logs.json").read_text())
    flights = plain(cfg.rig.logs.flights)
    accel = {}
    for f in sorted((raw / "processed").glob("*.csv")):
        name = flights.get(f.stem)
        if name and (extract / name / "imu.parquet").is_file():
            accel[name] = rig.accel_against_authors(pd.read_parquet(extract / name / "imu.parquet"),
                                                    pd.read_parquet(raw / "raw" / f"{f.stem}.parquet"), pd.read_csv(f))
    sync = json.loads((report_dir / "sync.json").read_text())
    filtered = json.loads((report_dir / "filter.json").read_text())
    with atomic_file(report_dir / "quality.md") as tmp:
        tmp.write_text(rig.quality_section(logs, sync, filtered, accel))
    with atomic_file(report_dir / "quality.json") as tmp:
        tmp.write_text(json_text({"flights": {n: {"kept": f["kept"], "rules": f["rules"]} for n, f in logs["flights"].items()},
                                  "accel_against_authors": accel}))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
