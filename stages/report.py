"""report: the benchmark report (results and cost tables as Markdown and LaTeX, figures, DVC plot data)."""

import logging
import os
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from nanosysid import protocol
from nanosysid.dataio import atomic_file, json_text
from nanosysid.errors import ConfigError
from nanosysid.metrics import QUANTITIES
from nanosysid.report import tables
from nanosysid.report.paper import PAPER_STATS
from nanosysid.report.stats import STAT_LABELS, trajectory_stats
from nanosysid.viz import figures
from stages.common import pick_flight, run_stage

log = logging.getLogger("nanosysid.report")

FIGURES = {
    "mae_horizon": "MAE against the prediction horizon on the test flights, one line per model "
                   "(log scale{oracle}).",
    "predictions": "{h}-step-ahead predictions against the ground truth on {flight}, {a:g} to {b:g} s "
                   "(the physics model holds ω constant, so its ω line is the naive one; models not in "
                   "report.lineplot.models are left out).",
    "trajectories": "Trajectory statistics of the dataset (mean over runs) beside the paper's real flights.",
}


def main(cfg: DictConfig) -> None:
    """``report.markdown`` and ``report.latex`` (results and cost tables), the figures in
    ``report.figures``, the MAE curves of every model in ``report.plots`` (CSV), and every model's
    SimErr per quantity in ``report.summary`` (JSON, the metrics experiments are compared on)."""
    rc = cfg.report
    a, b = rc.lineplot.window
    if not 0 <= a < b:  # before any output is written
        raise ConfigError(f"report.lineplot.window = [{a:g}, {b:g}] s: a window is a start >= 0 and a later end, in "
                          "seconds from the flight's start")
    names = list(cfg.models)
    horizons = [h for h in cfg.eval.table_horizons if h <= int(cfg.eval.horizon)]
    if len(horizons) < len(cfg.eval.table_horizons):
        log.warning("report: eval.table_horizons beyond eval.horizon = %d are left out of the tables: %s",
                    int(cfg.eval.horizon), [h for h in cfg.eval.table_horizons if h > int(cfg.eval.horizon)])
    rows = tables.load_scores(cfg.paths.eval, names)
    costs = tables.load_costs(cfg.paths.eval, names, cfg.paths.get("export"))
    H = next(iter(rows.values())).horizon

    bench = protocol.load(cfg.paths.split, horizon=H)
    flight = pick_flight(bench.test, rc.lineplot.flight, "report.lineplot.flight")
    fig_dir = Path(rc.figures)
    figures.mae_horizon_figure(rows, fig_dir / "mae_horizon.png")
    shown = [n for n in rc.lineplot.models if n in cfg.models]
    duration = float(flight.t[-1] - flight.t[0])
    if b > duration:
        log.warning("report.lineplot.window = [%g, %g] s reaches beyond flight %s (%.4g s): the figure shows %s", a, b,
                    flight.name, duration, "its part inside the flight" if a < duration else "the whole flight")
    # only the rollouts that end inside the window (and the smoothing's margin) are drawn
    t = flight.t - flight.t[0]
    inside = np.flatnonzero((t >= a) & (t <= b))
    lo, hi = (inside[0], inside[-1]) if len(inside) else (0, len(flight) - 1)
    margin = int(rc.lineplot.smooth)
    starts = np.arange(max(lo - margin - H, 0), min(hi + margin - H + 1, len(flight) - H))
    # the H-step-ahead predictions the evaluate stage kept while scoring: no model rolled out again
    ahead_rows = {}
    for n in shown:
        last = protocol.load_kept(Path(cfg.paths.eval) / n / "rollouts", [flight], horizon=H,
                                  stage=f"evaluate {n}")[flight.name].last
        ahead_rows[n] = np.full((len(flight), 13), np.nan)
        ahead_rows[n][starts + H] = last[starts]
    figures.predictions_figure(flight, ahead_rows, fig_dir / "predictions.png", horizon=H,
                               window=(a, b), smooth=int(rc.lineplot.smooth))
    figures.trajectory_stats_figure(trajectory_stats(bench.train + bench.test), PAPER_STATS, STAT_LABELS,
                                    fig_dir / "trajectories.png")

    rel = Path(rc.markdown).parent
    captions = [(_relative(fig_dir / f"{key}.png", rel),
                 text.format(h=H, flight=flight.name, a=a, b=b,
                             oracle="; the oracle, dashed, is the physical limit" if "oracle" in rows else ""))
                for key, text in FIGURES.items()]
    markdown = tables.benchmark_markdown(rows, costs, horizons, captions)
    if rc.get("note"):  # a profile's: these are not the benchmark's figures
        title, rest = markdown.split("\n", 1)
        markdown = f"{title}\n\n**{rc.note}**\n{rest}"
    with atomic_file(Path(rc.markdown)) as tmp:
        tmp.write_text(markdown)
    with atomic_file(Path(rc.latex)) as tmp:
        tmp.write_text(tables.results_table_tex(rows, horizons) + "\n" + tables.cost_table_tex(costs))
    with atomic_file(Path(rc.plots)) as tmp:
        tmp.write_text(tables.mae_csv(rows))
    with atomic_file(Path(rc.summary)) as tmp:
        tmp.write_text(json_text({"simerr": {name: {q: s.simerr[q] for q in QUANTITIES} for name, s in rows.items()}}))
    log.info("report: %d models, figures in %s", len(rows), fig_dir)



def _relative(path: Path, start: Path) -> str:
    return Path(os.path.relpath(path, start)).as_posix()


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
