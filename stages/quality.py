"""quality: the processed simulated flights against the simulator's truth and direct output."""

from pathlib import Path

from omegaconf import DictConfig

from nanosysid.cli import run_stage
from nanosysid.recording import pipeline
from nanosysid.vehicle import Vehicle


def main(cfg: DictConfig) -> None:
    r = cfg.recording
    pipeline.quality_report(
        r.flights_dir,
        r.bags_dir,
        Path(cfg.sim.out_dir) / "csv",
        Path(r.report_dir) / "sync.json",
        r.report_dir,
        vehicle=Vehicle.from_mapping(cfg.vehicle),
        test_trajectories=list(cfg.split.test),
        horizon=int(cfg.eval.horizon),
    )


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
