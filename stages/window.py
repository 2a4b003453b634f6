"""window: the initialization-window track: the models of ``window.models`` scored with the samples
before each window's start, and the data's limit of the angular velocity given them."""

import json
import logging
from pathlib import Path

import numpy as np

from omegaconf import DictConfig

from nanosysid import dynamics, protocol, window
from nanosysid.dataio import atomic_dir
from nanosysid.errors import DataError
from nanosysid.identify import identified_vehicle
from nanosysid.predictors import build_from_options
from nanosysid.report.window import beats_paper, paper_best, window_markdown
from stages.common import model_options, plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.window")


class _Memo:
    """A predictor that remembers its rollouts: the base's position and velocity are the same for
    the rate map fitted on every flight, the map refitted per reference, and holding the rate."""

    def __init__(self, predict):
        self.predict, self.seen = predict, {}

    def __call__(self, y0, u):
        import hashlib

        key = hashlib.sha1(np.ascontiguousarray(y0).tobytes() + np.ascontiguousarray(u).tobytes()).hexdigest()
        if key not in self.seen:
            self.seen[key] = np.array(np.asarray(self.predict(y0, u)), dtype=np.float64)
        return self.seen[key].copy()


class _Held:
    """Holding the rate: the base's rollouts with ω at its start value and the orientation
    integrated from it, as the rate map's own orientation is (the same integrator, so that the two
    rows differ by the rates alone)."""

    def __init__(self, base):
        self.base = base

    def __call__(self, y0, u):
        pred = np.array(np.asarray(self.base(y0, u)), dtype=np.float64)
        w = np.repeat(np.asarray(y0)[:, None, 10:13], u.shape[1], axis=1)
        pred[..., 10:13] = w
        pred[..., 6:10] = window.orientation(np.asarray(y0)[:, 6:10], np.asarray(y0)[:, 10:13], w)
        return pred


def main(cfg: DictConfig) -> dict:
    """Write ``<window.out_dir>/report.md`` and ``scores.json``."""
    wc = cfg.window
    H, W, batch = int(cfg.eval.horizon), int(wc.init), int(cfg.eval.batch_size)
    bench = protocol.load(cfg.paths.split, horizon=H)
    # a flight too short for a window and its history has no window on the track
    train, test = ([f for f in flights if len(f) > W + H] for flights in (bench.train, bench.test))
    short = sorted(f.name for f in bench.train + bench.test if len(f) <= W + H)
    if not test or not train:
        raise DataError(f"{cfg.paths.split}: no {'test' if not test else 'training'} flight is longer than "
                        f"window.init + eval.horizon = {W + H} samples: the track has no window to score; lower "
                        "window.init")
    names = list(plain(wc.models))
    predictors = {name: build_from_options(model_options(cfg, name)) for name in names}
    scores = {name: window.evaluate(p, test, horizon=H, init=W, batch_size=batch) for name, p in predictors.items()}
    base_name = str(wc.base)
    base = _Memo(predictors[base_name] if base_name in predictors else build_from_options(model_options(cfg, base_name)))
    vehicle = identified_vehicle(vehicle_of(cfg), wc.identified)
    torque_map = dynamics.mixer_matrix(k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm).numpy()[1:]
    held = _Held(base)
    rate_map = window.fit_rate_map(train, base=base, torque_map=torque_map, inertia=vehicle.inertia, horizon=H,
                                   init=W, ridge=float(wc.ridge))
    maps = {"in_sample": window.evaluate(rate_map, train, horizon=H, init=W, batch_size=batch)}
    if window.references(train) >= 2:
        maps["held_out"] = window.held_out_rate_map(rate_map, train, horizon=H, init=W, batch_size=batch)
    maps["test"] = window.evaluate(rate_map, test, horizon=H, init=W, batch_size=batch)
    holds = {"in_sample": window.evaluate(held, train, horizon=H, init=W, batch_size=batch)}
    holds["held_out"] = holds["in_sample"]  # holding the rate fits nothing: held out is in sample
    holds["test"] = window.evaluate(held, test, horizon=H, init=W, batch_size=batch)
    source = "the " + ("real flights" if cfg.data.get("source") == "rig" else f"data of `{cfg.paths.split}`")
    record = {
        "format": "nanosysid-window-1", "init": W, "horizon": H, "base": base_name, "left_out": short,
        "models": {n: s.to_dict() for n, s in scores.items()},
        "beats_paper": {n: beats_paper(s.simerr) for n, s in scores.items()},
        "paper_best": {q: {"model": m, "simerr": v} for q, (m, v) in paper_best().items()},
        "rate_map": {k: s.to_dict() for k, s in maps.items()},
        "held": {k: s.to_dict() for k, s in holds.items() if k != "held_out"},
    }
    out = Path(wc.out_dir)
    with atomic_dir(out, inputs=[cfg.paths.split]) as tmp:
        (tmp / "scores.json").write_text(json.dumps(record, indent=1, allow_nan=False) + "\n")
        (tmp / "report.md").write_text(window_markdown(init=W, horizon=H, scores=scores, rate_map=maps, hold=holds,
                                                       features=window.RATE_FEATURES, base=base_name, source=source,
                                                       left_out=short))
    log.info("window (W = %d): %s; rate map ω %.4g against %.4g held (test)", W,
             "; ".join(f"{n} ω {s.simerr['w']:.4g}" for n, s in scores.items()),
             maps["test"].simerr["w"], holds["test"].simerr["w"])
    return record


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
