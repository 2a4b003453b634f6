"""compare: the dataset and the benchmark's results against the paper's real flights
(trajectory statistics, the naive and physics rows, the pattern of the results), and the
simulated world's effects."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import identify, protocol
from nanosysid.dataio import atomic_file, json_text
from nanosysid.report import paper, tables
from nanosysid.report.stats import stats_markdown, trajectory_stats
from nanosysid.report.world import nature_thrust_coefficient, world_markdown
from stages.common import plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.compare")


def main(cfg: DictConfig) -> None:
    """``<paths.sim_report>/stats.md`` (and ``stats.json``: the figures and each criterion's verdict)."""
    names = [m for m in paper.PAPER_MODELS if m in cfg.models]
    scores = tables.load_scores(cfg.paths.eval, names)
    bench = protocol.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    comparison = paper.compare_results(scores)
    source = str(cfg.data.source)
    parts = ["# The dataset against the paper's real flights", "",
             f"Data: `{source}` flights ({len(bench.train)} for training, {len(bench.test)} for testing); every model "
             "scored on the test flights by the evaluate stage.", ""]
    if source.startswith("sim"):
        parts.append(world_markdown(plain(cfg.sim.effects)))
    parts.append(stats_markdown(trajectory_stats(bench.train + bench.test)).replace("# ", "## ", 1))
    if source.startswith("sim"):
        params = identify.read_identified(Path(cfg.identify.out_dir) / "params.json")
        vehicle = vehicle_of(cfg)
        paper.compare_identification(comparison, params, k_f=vehicle.k_f, k_m=vehicle.k_m,
                                     k_f_thrust=nature_thrust_coefficient(Path(cfg.sim.out_dir) / "csv",
                                                                         params["train_flights"]))
        parts.append(paper.identification_markdown(comparison))
    parts.append(paper.results_markdown(comparison))
    out = Path(cfg.paths.sim_report)
    with atomic_file(out / "stats.md") as tmp:
        tmp.write_text("\n".join(parts))
    with atomic_file(out / "stats.json") as tmp:
        tmp.write_text(json_text(comparison.to_dict()))
    log.info("compare: %s", ", ".join(f"{k}: {'yes' if v else 'no'}" for k, v in comparison.checks.items()))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
