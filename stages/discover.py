"""discover: where the nominal model and the measurements disagree, the effects that explain it,
the augmented model physics+<effects>, and the report."""

import logging
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from nanosysid import discover, protocol, sim
from nanosysid.dataio import atomic_dir
from nanosysid.discover.fit import ChainFilter
from nanosysid.discover.model import save_discovered
from nanosysid.effects import entry
from nanosysid.identify import identified_vehicle, read_identified
from nanosysid.report.discovery import write_report
from nanosysid.sim.world import DEFAULT_WORLD, REGISTRY, state_effects
from stages.common import plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.discover")


def main(cfg: DictConfig) -> discover.DiscoveryResult:
    """Run :func:`nanosysid.discover.run` on ``paths.split`` with the identify stage's k_F and
    k_M; write ``<discover.out_dir>/model.json`` and ``<discover.report_dir>/`` (report,
    result, figures)."""
    dc = cfg.discover
    oracle = limit = held_limit = world = None
    if dc.oracle is not None:
        # the oracle built here, not through the registry of every model (which loads every network)
        options = {k: v for k, v in plain(dc.oracle).items() if k not in ("kind", "artifact", "code")}
        oracle = sim.oracle_of(**options)
        effects = dict(options.get("effects") or DEFAULT_WORLD)
        # the world beside the verdicts, in the report only: discovery never sees it
        world = {k: {"strength": float(s), "described_by": sorted(REGISTRY[k].described_by)}
                 for k, s in effects.items() if float(s)}
        # the limit of a model of the state: the true dynamics without the effects of time
        of_state = {**options, "effects": state_effects(effects), "seed": int(options.get("seed", 0))}
        limit = sim.oracle_of(**of_state)
        # ... and with the angular velocity held: the limit of a model on the paper's physics base
        held_limit = sim.oracle_of(**of_state, held=True)
    H = int(cfg.eval.horizon)
    bench = protocol.load(cfg.paths.split, horizon=H)
    vehicle = identified_vehicle(vehicle_of(cfg), dc.identified)
    delays = np.arange(1, int(round(float(dc.delay_max) / float(dc.delay_step))) + 1) * float(dc.delay_step)
    result = discover.run(bench.train, bench.test, vehicle=vehicle, alpha=float(dc.alpha), share=float(dc.share),
                          block=float(dc.block), folds=int(dc.folds), sindy=bool(dc.sindy),
                          delays=tuple(delays), window=int(dc.savgol_window), order=int(dc.savgol_order), horizon=H,
                          oracle=oracle, limit=limit, held_limit=held_limit, inertia_z_range=tuple(cfg.identify.inertia_z_range),
                          batch_size=int(cfg.eval.batch_size), flights_out=bool(dc.flights_out), progress=True,
                          velocity=str(dc.velocity), noise_draws=int(dc.noise_draws),
                          chain=ChainFilter(**plain(dc.chain)))
    step = result.model.step
    effects = {name: {"params": list(entry(name).params), "coefficients": coef}
               for name, coef in step.coefficients().items()}
    with atomic_dir(Path(dc.report_dir), inputs=[cfg.paths.split]) as tmp:
        write_report(result, tmp, nominal=_nominal_source(dc.identified), world=world)
        # the model last, once its report is whole: a report that fails leaves no model behind
        save_discovered(Path(dc.out_dir) / "model.json", result.vehicle, effects, result.model.delay,
                        dt=step.dt, substeps=step.substeps, integrated=step.integrated)
    log.info("discover: %s; SimErr p %.3g -> %.3g, v %.3g -> %.3g, R %.3g -> %.3g, w %.3g -> %.3g", result.name,
             *(x for q in "pvRw" for x in (result.before.simerr[q], result.after.simerr[q])))
    return result


def _nominal_source(identified) -> str:
    """Where the nominal k_F and k_M come from, in words for the report."""
    if identified is None:
        return "the configured vehicle's (`discover.identified: null`)"
    d = read_identified(identified)

    def by(fit: str) -> str:
        record = d.get(fit)
        estimator = record.get("estimator") if isinstance(record, dict) else None
        return f" by {estimator}" if estimator else ""

    return f"from the identify stage's {Path(identified).name}: k_F{by('thrust_fit')}; k_M{by('yaw_fit')}"


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
