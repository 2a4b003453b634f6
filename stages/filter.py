"""filter: fill short gaps and low-pass each signal group; write the flights as published CSVs."""

from omegaconf import DictConfig

from nanosysid.consistency import Expect
from nanosysid.preprocess.filtering import FilterConfig, filter_folder
from stages.common import plain, run_stage


def main(cfg: DictConfig) -> None:
    r = cfg.preprocess
    filter_folder(r.sync_dir, r.flights_dir, r.report_dir, FilterConfig.from_mapping(plain(r.filter)),
                  Expect(float(cfg.vehicle.mass), float(cfg.vehicle.k_f), float(cfg.vehicle.gravity)))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
