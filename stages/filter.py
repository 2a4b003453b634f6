"""filter: fill short gaps and low-pass each signal group; write the flights as published CSVs."""

from omegaconf import DictConfig

from nanosysid.preprocess.filtering import FilterConfig, filter_folder
from stages.common import plain, run_stage


def main(cfg: DictConfig) -> None:
    r = cfg.preprocess
    filter_folder(r.sync_dir, r.flights_dir, r.report_dir, FilterConfig.from_mapping(plain(r.filter)))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
