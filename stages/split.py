"""split: assign the flights of the data folder to train/ and test/ by trajectory."""

from omegaconf import DictConfig

from nanosysid import splitting
from nanosysid.consistency import Expect
from stages.common import run_stage


def main(cfg: DictConfig) -> None:
    splitting.split_folder(
        cfg.data.flights_dir,
        cfg.paths.split,
        train=list(cfg.split.train),
        test=list(cfg.split.test),
        horizon=cfg.eval.horizon,
        expect=Expect(float(cfg.vehicle.mass), float(cfg.vehicle.k_f), float(cfg.vehicle.gravity)),
    )


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
