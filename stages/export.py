"""export: a model's step to ONNX (checked with onnxruntime) and to C99, with its cost per step."""

from omegaconf import DictConfig

from nanosysid.cli import run_stage
from nanosysid.export import pipeline


def main(cfg: DictConfig, model: str) -> None:
    pipeline.export_model(cfg, model)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
