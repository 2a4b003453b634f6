"""visualize: a rerun recording per test flight, every model's rollouts against the measurements."""

from omegaconf import DictConfig

from nanosysid import reporting
from nanosysid.cli import run_stage


def main(cfg: DictConfig) -> None:
    reporting.write_recordings(cfg)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
