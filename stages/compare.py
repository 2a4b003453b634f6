"""compare: the dataset and the benchmark's results against the paper's real flights
(trajectory statistics, the naive and physics rows, the pattern of the results), and the
simulated world's effects."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import benchmark, identify
from nanosysid.dataio import atomic_file, json_text, read_flight_csv
from nanosysid.report import paper, tables
from nanosysid.sim.simulator import collective_thrust_coefficient
from nanosysid.report.stats import stats_markdown, trajectory_stats
from nanosysid.sim.world import DEFAULT_WORLD, DEPENDS_ON, EFFECTS
from stages.common import plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.compare")


def world_markdown(strengths: dict[str, float]) -> str:
    """The simulated world's effects: strength in this dataset, what each does, what it depends on."""
    L = ["## The simulated world", "",
         "Effects of nature in this dataset (`sim.effects`; 1.0 is a realistic magnitude, 0 off). Only the ones that "
         "depend on the state and the rotor speeds can a model learn; the turbulence is new in every flight.", "",
         "| effect | strength | default world | depends on | what it does |", "|---|---|---|---|---|"]
    for name, text in EFFECTS.items():
        L.append(f"| `{name}` | {float(strengths.get(name, 0.0)):g} | {DEFAULT_WORLD.get(name, 0.0):g} | "
                 f"{DEPENDS_ON[name]} | {text} |")
    return "\n".join(L) + "\n"


def nature_thrust_coefficient(direct_dir: Path, names: list[str]) -> float | None:
    """:func:`~nanosysid.sim.simulator.collective_thrust_coefficient` of the flights ``names`` of
    the simulator's direct output (None where they are not there)."""
    files = [direct_dir / f"{n}.csv" for n in names]
    if not names or not all(f.exists() for f in files):
        return None
    return collective_thrust_coefficient([read_flight_csv(f) for f in files])


def main(cfg: DictConfig) -> None:
    """``<paths.sim_report>/stats.md`` (and ``stats.json``: the figures and each criterion's verdict)."""
    names = [m for m in paper.PAPER_MODELS if m in cfg.models]
    scores = tables.load_scores(cfg.paths.eval, names)
    bench = benchmark.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
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
