"""identify: least-squares k_F and k_M on the training flights; figure on a test flight."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import benchmark, identify
from nanosysid.errors import DataError
from nanosysid.viz.identify import identify_figure
from stages.common import run_stage, vehicle_of

log = logging.getLogger("nanosysid.identify")


def main(cfg: DictConfig) -> None:
    c = cfg.identify
    bench = benchmark.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    if not bench.train:
        raise DataError(f"{Path(cfg.paths.split) / 'train'}: no flight CSV files to fit k_F and k_M on")
    vehicle = vehicle_of(cfg)
    thrust, yaw = identify.identify(bench.train, vehicle, window=int(c.savgol_window), polyorder=int(c.savgol_order))
    out = Path(c.out_dir)
    identify.save_params(out / "params.json", thrust, yaw, bench.train)
    for name, fit in (("k_F", thrust), ("k_M", yaw)):
        lo, hi = fit.ci95 if fit.ci95 is not None else (float("nan"), float("nan"))
        log.info("%s = %.4g (95 %% interval %.4g to %.4g over %d flights; R^2 %.2f), by %s", name, fit.coef, lo, hi,
                 fit.flights, fit.r2, fit.estimator)
    log.warning("closed-loop bias %s", identify.CLOSED_LOOP_BIAS)
    identify_figure(bench.test[0], vehicle, thrust, yaw, out / "identify.png")


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
