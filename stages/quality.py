"""quality: the processed simulated flights against the simulator's truth and direct output."""

from pathlib import Path

from omegaconf import DictConfig

from nanosysid.report.quality import quality_report
from stages.common import run_stage, vehicle_of


def main(cfg: DictConfig) -> None:
    r = cfg.preprocess
    quality_report(
        r.flights_dir,
        r.bags_dir,
        Path(cfg.sim.out_dir) / "csv",
        Path(r.report_dir) / "sync.json",
        r.report_dir,
        vehicle=vehicle_of(cfg),
        test_trajectories=list(cfg.split.test),
        horizon=int(cfg.eval.horizon),
        lag_tolerance=float(r.sync.lag_tolerance),
    )


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
