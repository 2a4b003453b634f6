"""mcu: a model's generated C built for the Cortex-M4F, run on QEMU's STM32F405, checked against
PyTorch float32, its instructions per step, flash and RAM measured."""

from omegaconf import DictConfig

from nanosysid.cli import run_stage
from nanosysid.export import pipeline


def main(cfg: DictConfig, model: str) -> None:
    pipeline.mcu_model(cfg, model)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
