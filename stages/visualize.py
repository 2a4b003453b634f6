"""visualize: a rerun recording per test flight, every model's rollouts against the measurements (and
discovery's verdicts, when the discovered model is among them)."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import protocol
from nanosysid.dataio import atomic_dir
from nanosysid.viz.rerun import write_recording
from nanosysid.predictors import build_from_options
from stages.common import model_options, run_stage

log = logging.getLogger("nanosysid.visualize")


def main(cfg: DictConfig) -> list[Path]:
    """One rerun recording per test flight in ``visualize.out_dir`` (replaced as a whole)."""
    H = int(cfg.eval.horizon)
    bench = protocol.load(cfg.paths.split, horizon=H)
    models = {n: build_from_options(model_options(cfg, n)) for n in cfg.models}
    out = Path(cfg.visualize.out_dir)
    verdicts = None
    notes = Path(cfg.discover.report_dir) / "verdicts.md"
    if "discovered" in cfg.models and notes.is_file():
        verdicts = notes.read_text()
    written = []
    with atomic_dir(out, inputs=[cfg.paths.split]) as tmp:
        for flight in bench.test:
            rollouts = {name: protocol.predictions(p, flight, horizon=H) for name, p in models.items()}
            write_recording(flight, rollouts, tmp / f"{flight.name}.rrd", stride=int(cfg.visualize.stride),
                            verdicts=verdicts)
            written.append(out / f"{flight.name}.rrd")
            log.info("visualize: %s", written[-1])
    return written


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
