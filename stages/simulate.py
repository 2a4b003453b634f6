"""simulate: generate the default dataset's flight CSVs."""

from omegaconf import DictConfig

from nanosysid import datasets
from nanosysid.cli import run_stage


def main(cfg: DictConfig) -> None:
    datasets.write_default_dataset(cfg)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
