"""filter: fill short gaps and low-pass each signal group; write the flights as published CSVs."""

from omegaconf import DictConfig, OmegaConf

from nanosysid.cli import run_stage
from nanosysid.recording import pipeline
from nanosysid.recording.filtering import FilterConfig


def main(cfg: DictConfig) -> None:
    r = cfg.recording
    filter_cfg = FilterConfig.from_mapping(OmegaConf.to_container(r.filter, resolve=True))
    pipeline.filter_folder(r.sync_dir, r.flights_dir, r.report_dir, filter_cfg)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
