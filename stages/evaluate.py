"""evaluate: score one model on the test flights with the multi-horizon protocol."""

from omegaconf import DictConfig

from nanosysid import evaluation
from nanosysid.cli import run_stage


def main(cfg: DictConfig, model: str) -> None:
    evaluation.evaluate_model(cfg, model)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
