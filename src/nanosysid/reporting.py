"""The report stage's work: tables, figures and the DVC plot data of all evaluated models."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from nanosysid import benchmark, report
from nanosysid.config import ConfigError
from nanosysid.dataio import Flight, atomic_file
from nanosysid.models import build_from_config
from nanosysid.sim.stats import PAPER_STATS, STAT_LABELS, trajectory_stats
from nanosysid.viz import report as figures
from nanosysid.viz.signals import ahead

__all__ = ["write_report", "write_recordings", "model_predictors", "pick_flight"]

log = logging.getLogger(__name__)

FIGURES = {
    "mae_horizon": "MAE against the prediction horizon on the test flights, one line per model "
                   "(log scale; the oracle, dashed, is the physical limit).",
    "predictions": "{h}-step-ahead predictions against the ground truth on {flight}, {a:g} to {b:g} s "
                   "(the physics model holds ω constant, so its ω line is the naive one; models not in "
                   "report.lineplot.models are left out).",
    "trajectories": "Trajectory statistics of the dataset (mean over runs) beside the paper's real flights.",
}


def model_predictors(cfg: DictConfig, names: list[str] | None = None) -> dict[str, Any]:
    """A predictor for each model of the config (all of ``cfg.models`` by default), through
    the one model builder evaluation also uses."""
    names = list(cfg.models) if names is None else names
    return {n: build_from_config(OmegaConf.to_container(cfg.models[n], resolve=True)) for n in names}


def pick_flight(flights: list[Flight], name: str | None, key: str) -> Flight:
    """The flight called ``name`` (a prefix of its file name will do), the first one when None."""
    if name is None:
        return flights[0]
    hits = [f for f in flights if f.name == name or f.name.startswith(name)]
    if not hits:
        raise ConfigError(f"{key}: no test flight named {name!r} (there are: {', '.join(f.name for f in flights)})")
    return hits[0]


def write_report(cfg: DictConfig) -> None:
    """``report.markdown`` and ``report.latex`` (results and cost tables), the figures in
    ``report.figures``, and the MAE curves of every model in ``report.plots`` (CSV)."""
    rc = cfg.report
    names = list(cfg.models)
    horizons = [h for h in cfg.eval.table_horizons if h <= int(cfg.eval.horizon)]
    rows = report.load_scores(cfg.paths.eval, names)
    costs = report.load_costs(cfg.paths.eval, names, cfg.paths.get("export"))
    H = next(iter(rows.values())).horizon

    bench = benchmark.load(cfg.paths.split, horizon=H)
    flight = pick_flight(bench.test, rc.lineplot.flight, "report.lineplot.flight")
    fig_dir = Path(rc.figures)
    figures.mae_horizon_figure(rows, fig_dir / "mae_horizon.png")
    shown = [n for n in rc.lineplot.models if n in cfg.models]
    a, b = rc.lineplot.window
    # only the rollouts that end inside the window (and the smoothing's margin) are drawn
    t = flight.t - flight.t[0]
    inside = np.flatnonzero((t >= a) & (t <= b))
    lo, hi = (inside[0], inside[-1]) if len(inside) else (0, len(flight) - 1)
    margin = int(rc.lineplot.smooth)
    starts = np.arange(max(lo - margin - H, 0), min(hi + margin - H + 1, len(flight) - H))
    ahead_rows = {name: ahead(benchmark.predictions(p, flight, horizon=H, starts=starts), H, len(flight), starts)
                  for name, p in model_predictors(cfg, shown).items()}
    figures.predictions_figure(flight, ahead_rows, fig_dir / "predictions.png", horizon=H,
                               window=(a, b), smooth=int(rc.lineplot.smooth))
    figures.trajectory_stats_figure(trajectory_stats(bench.train + bench.test), PAPER_STATS, STAT_LABELS,
                                    fig_dir / "trajectories.png")

    rel = Path(rc.markdown).parent
    captions = [(_relative(fig_dir / f"{key}.png", rel),
                 text.format(h=H, flight=flight.name, a=a, b=b)) for key, text in FIGURES.items()]
    with atomic_file(Path(rc.markdown)) as tmp:
        tmp.write_text(report.benchmark_markdown(rows, costs, horizons, captions))
    with atomic_file(Path(rc.latex)) as tmp:
        tmp.write_text(report.results_table_tex(rows, horizons) + "\n" + report.cost_table_tex(costs))
    with atomic_file(Path(rc.plots)) as tmp:
        tmp.write_text(report.mae_csv(rows))
    log.info("report: %d models, figures in %s", len(rows), fig_dir)


def _relative(path: Path, start: Path) -> str:
    import os

    return Path(os.path.relpath(path, start)).as_posix()


def write_recordings(cfg: DictConfig) -> list[Path]:
    """One rerun recording per test flight in ``visualize.out_dir`` (replaced as a whole)."""
    from nanosysid.dataio import atomic_dir
    from nanosysid.viz.recording import write_recording

    H = int(cfg.eval.horizon)
    bench = benchmark.load(cfg.paths.split, horizon=H)
    predictors = model_predictors(cfg)
    out = Path(cfg.visualize.out_dir)
    written = []
    with atomic_dir(out) as tmp:
        for flight in bench.test:
            rollouts = {name: benchmark.predictions(p, flight, horizon=H) for name, p in predictors.items()}
            write_recording(flight, rollouts, tmp / f"{flight.name}.rrd", stride=int(cfg.visualize.stride))
            written.append(out / f"{flight.name}.rrd")
            log.info("visualize: %s", written[-1])
    return written
