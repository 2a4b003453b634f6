"""results: the benchmark table of every evaluated model, in the layout of the paper's table."""

from pathlib import Path

from omegaconf import DictConfig

from nanosysid import report
from nanosysid.cli import run_stage
from nanosysid.dataio import atomic_file


def main(cfg: DictConfig) -> None:
    rows = report.load_scores(Path(cfg.paths.eval), list(cfg.models))
    with atomic_file(Path(cfg.paths.results)) as tmp:
        tmp.write_text(report.results_markdown(rows, list(cfg.eval.table_horizons)))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
