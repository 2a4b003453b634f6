"""extract: each ROS 2 bag -> one parquet table per stream, in SI units."""

from omegaconf import DictConfig, OmegaConf

from nanosysid.cli import run_stage
from nanosysid.recording import pipeline


def main(cfg: DictConfig) -> None:
    r = cfg.recording
    pipeline.extract_folder(r.bags_dir, r.extract_dir, OmegaConf.to_container(r.topics, resolve=True))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
