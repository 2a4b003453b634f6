"""split: assign the flights of the data folder to train/ and test/ by trajectory."""

from omegaconf import DictConfig

from nanosysid import splitting
from stages.common import run_stage


def main(cfg: DictConfig) -> None:
    splitting.split_folder(
        cfg.data.flights_dir,
        cfg.paths.split,
        train=list(cfg.split.train),
        test=list(cfg.split.test),
        horizon=cfg.eval.horizon,
    )


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
