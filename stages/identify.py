"""identify: least-squares k_F and k_M on the training flights; figure on a test flight."""

import json
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import benchmark, identify
from nanosysid.cli import run_stage
from nanosysid.dataio import atomic_file
from nanosysid.vehicle import Vehicle
from nanosysid.viz.identify import identify_figure


def main(cfg: DictConfig) -> None:
    c = cfg.identify
    bench = benchmark.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    vehicle = Vehicle.from_mapping(cfg.vehicle)
    thrust = identify.fit_thrust(bench.train, vehicle)
    yaw = identify.fit_yaw_moment(bench.train, vehicle, window=int(c.savgol_window), polyorder=int(c.savgol_order))
    out = Path(c.out_dir)
    result = {
        "k_f": thrust.coef, "k_m": yaw.coef,
        "thrust_fit": thrust.to_dict(), "yaw_fit": yaw.to_dict(),
        "train_flights": [f.name for f in bench.train],
    }
    with atomic_file(out / "params.json") as tmp:
        tmp.write_text(json.dumps(result, indent=1) + "\n")
    identify_figure(bench.test[0], vehicle, thrust, yaw, out / "identify.png")


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
