"""report: the benchmark report (results and cost tables as Markdown and LaTeX, figures, DVC plot data)."""

from omegaconf import DictConfig

from nanosysid import reporting
from nanosysid.cli import run_stage


def main(cfg: DictConfig) -> None:
    reporting.write_report(cfg)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
