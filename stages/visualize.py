"""visualize: a rerun recording per test flight, every model's rollouts against the measurements (and
discovery's verdicts, when the discovered model is among them). The rollouts are those the evaluate
stage kept while scoring each model: no model is rolled out again here."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import protocol
from nanosysid.dataio import atomic_dir
from nanosysid.viz.rerun import write_recording
from stages.common import run_stage

log = logging.getLogger("nanosysid.visualize")


def main(cfg: DictConfig) -> list[Path]:
    """One rerun recording per test flight in ``visualize.out_dir`` (replaced as a whole)."""
    H = int(cfg.eval.horizon)
    bench = protocol.load(cfg.paths.split, horizon=H)
    stride = int(cfg.visualize.stride)
    kept = {n: protocol.load_kept(Path(cfg.paths.eval) / n / "rollouts", bench.test, horizon=H, stride=stride,
                                  stage=f"evaluate {n}") for n in cfg.models}
    out = Path(cfg.visualize.out_dir)
    verdicts = None
    notes = Path(cfg.discover.report_dir) / "verdicts.md"
    if "discovered" in cfg.models and notes.is_file():
        verdicts = notes.read_text()
    written = []
    with atomic_dir(out, inputs=[cfg.paths.split]) as tmp:
        for flight in bench.test:
            rollouts = {name: k[flight.name] for name, k in kept.items()}
            write_recording(flight, rollouts, tmp / f"{flight.name}.rrd", verdicts=verdicts)
            written.append(out / f"{flight.name}.rrd")
            log.info("visualize: %s", written[-1])
    return written


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
