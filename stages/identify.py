"""identify: least-squares k_F and k_M on the training flights; figure on a test flight."""

from pathlib import Path

from omegaconf import DictConfig

from nanosysid import benchmark, identify
from nanosysid.errors import DataError
from nanosysid.viz.identify import identify_figure
from stages.common import run_stage, vehicle_of


def main(cfg: DictConfig) -> None:
    c = cfg.identify
    bench = benchmark.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    if not bench.train:
        raise DataError(f"{Path(cfg.paths.split) / 'train'}: no flight CSV files to fit k_F and k_M on")
    vehicle = vehicle_of(cfg)
    thrust, yaw = identify.identify(bench.train, vehicle, window=int(c.savgol_window), polyorder=int(c.savgol_order))
    out = Path(c.out_dir)
    identify.save_params(out / "params.json", thrust, yaw, bench.train)
    identify_figure(bench.test[0], vehicle, thrust, yaw, out / "identify.png")


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
