"""train: fit one learned model on the training flights (multi-step rollout loss)."""

from omegaconf import DictConfig

from nanosysid.cli import run_stage
from nanosysid.models.train_stage import train_from_config


def main(cfg: DictConfig, model: str) -> None:
    train_from_config(cfg, model)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
