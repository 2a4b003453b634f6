"""discover: where the nominal model and the measurements disagree, the effects that explain it,
the augmented model physics+<effects>, and the report."""

from omegaconf import DictConfig

from nanosysid.cli import run_stage
from nanosysid.discover.stage import discover_from_config


def main(cfg: DictConfig) -> None:
    discover_from_config(cfg)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
