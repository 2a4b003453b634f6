"""filter: fill short gaps and low-pass each signal group; write the flights as published CSVs."""

import logging
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig
from tqdm.auto import tqdm

from nanosysid.bags.filtering import FilterConfig, filter_flight
from nanosysid.dataio import atomic_dir, write_flight_csv
from nanosysid.errors import DataError
from stages.common import plain, run_stage, write_json

log = logging.getLogger("nanosysid.filter")


def filter_folder(sync_dir: Path, out_dir: Path, report_dir: Path, cfg: FilterConfig) -> list[dict]:
    """Filter every synchronised flight into ``out_dir/<flight>.csv`` (the published schema)."""
    files = sorted(Path(sync_dir).glob("*.parquet"))
    if not files:
        raise DataError(f"{sync_dir}: no synchronised flights")
    reports = []
    with atomic_dir(out_dir, inputs=[sync_dir]) as tmp:
        for f in tqdm(files, desc="filter", unit="flight", disable=None):
            flight, rep = filter_flight(f.stem, pd.read_parquet(f), cfg)
            write_flight_csv(flight, tmp / f"{f.stem}.csv")
            for group, runs in rep["gaps_left"].items():
                log.warning("%s: %s has %d gap(s) longer than %d samples, left unfilled",
                            f.stem, group, len(runs), cfg.max_gap)
            reports.append(rep)
    write_json(Path(report_dir) / "filter.json", reports)
    return reports


def main(cfg: DictConfig) -> None:
    r = cfg.recording
    filter_folder(r.sync_dir, r.flights_dir, r.report_dir, FilterConfig.from_mapping(plain(r.filter)))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
