"""identify: least-squares k_F and k_M on the training flights; figure on a test flight."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import identify, protocol
from nanosysid.dataio import flight_catalog, parse_flight_name, read_flight_csv
from nanosysid.errors import DataError
from nanosysid.viz.identify import identify_figure
from stages.common import run_stage, vehicle_of

log = logging.getLogger("nanosysid.identify")


def main(cfg: DictConfig) -> None:
    c = cfg.identify
    bench = protocol.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    if not bench.train:
        raise DataError(f"{Path(cfg.paths.split) / 'train'}: no flight CSV files to fit k_F and k_M on")
    vehicle = vehicle_of(cfg)
    window, order = int(c.savgol_window), int(c.savgol_order)
    thrust, yaw_paper = identify.identify(bench.train, vehicle, window=window, polyorder=order)
    calibration = calibration_flights(Path(cfg.data.flights_dir), list(c.calibration))
    yaw = yaw_paper
    if calibration:
        yaw = identify.fit_yaw_moment_iv(calibration, vehicle, window=window, polyorder=order,
                                         lags=[float(x) for x in c.iv_lags], blocks=int(c.iv_blocks))
    identify.check_plausible(thrust, yaw, vehicle)
    jz_range = c.get("inertia_z_range")
    yaw, yaw_paper = (identify.with_inertia_range(f, vehicle.inertia[2], jz_range) for f in (yaw, yaw_paper))
    out = Path(c.out_dir)
    identify.write_identified(out / "params.json", thrust, yaw, bench.train, yaw_paper=yaw_paper if calibration else None,
                         calibration=calibration)
    for name, fit in (("k_F", thrust), ("k_M", yaw)) + ((("k_M, the paper's method", yaw_paper),) if calibration else ()):
        lo, hi = fit.ci95 if fit.ci95 is not None else (float("nan"), float("nan"))
        log.info("%s = %.4g (95 %% interval %.4g to %.4g; R^2 %.2f), by %s", name, fit.coef, lo, hi, fit.r2,
                 fit.estimator)
        if fit.ci95_inertia is not None:
            log.info("%s: 95 %% interval %.4g to %.4g with the yaw inertia anywhere in %.4g to %.4g kg m^2 (the "
                     "flights identify k_M / J_z)", name, *fit.ci95_inertia, *fit.inertia_z_range)
    if not calibration:
        log.warning("no calibration flight (trajectories %s in %s): closed-loop bias %s", list(c.calibration),
                    cfg.data.flights_dir, identify.CLOSED_LOOP_BIAS)
    identify_figure(bench.test[0], vehicle, thrust, yaw, out / "identify.png")


def calibration_flights(folder: Path, trajectories: list[str]) -> list:
    """The flights of ``folder`` (searched below it, named as the split names them) whose
    trajectory is one of ``trajectories``."""
    if not trajectories or not folder.is_dir():
        return []
    return [read_flight_csv(f.path, name=f.name) for f in flight_catalog(folder)
            if parse_flight_name(f.name)[0] in trajectories]


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
