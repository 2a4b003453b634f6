"""extract: each ROS 2 bag -> one parquet table per stream, in SI units."""

from omegaconf import DictConfig

from nanosysid.bags.extract import extract_folder
from stages.common import plain, run_stage


def main(cfg: DictConfig) -> None:
    r = cfg.preprocess
    extract_folder(r.bags_dir, r.extract_dir, plain(r.topics))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
