"""The benchmark's protocol: load flights, cut windows, score any predictor as the paper does.

A predictor is ``predict(y0 (B, 13), u (B, H, 4)) -> (B, H, 13)`` (numpy or torch). For
every admissible start ``t in {0, ..., T-H-1}`` of a flight it receives ``y_t`` and
``u_{t..t+H-1}`` and predicts ``y_{t+1..t+H}`` open loop. Each flight gives ``T - H``
windows. A predictor with ``timed = True`` (the simulator's oracle, which replays what
happened at that time of that flight) is also given ``t0=`` each window's start time (B,) in
s from the flight's first sample, and ``flight=`` the flight's name.

Example::

    from nanosysid import predictors, protocol
    bench = protocol.load("path/to/data")        # train/ and test/ flight CSVs
    scores = protocol.evaluate(predictors.predictor("physics"), bench.test, horizon=50)
    scores.mae["p"][9], scores.simerr["v"]
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from nanosysid import metrics
from nanosysid.consistency import NO_LOAD_SPEED
from nanosysid.dataio import (INPUT_COLUMNS, OUTPUT_COLUMNS, SAMPLE_PERIOD, Flight, atomic_file, check_distinct,
                              flight_catalog, flight_list, parse_flight_name, read_flight_csv)
from nanosysid.errors import ConfigError, DataError, PredictionError
from nanosysid.numerics import LOOP_THREADS, threads

__all__ = ["Benchmark", "Flight", "Scores", "Kept", "evaluate", "load", "save_kept", "load_kept", "predictions", "score", "windows", "check_flight", "check_predictions",
           "template_frame", "write_template", "QUAT_NORM_TOLERANCE", "flight_list"]

Predictor = Callable[[Any, Any], Any]

QUAT_NORM_TOLERANCE = 0.01  # a predicted quaternion further than this from unit norm is refused


@dataclass
class Benchmark:
    """Training and test flights of one dataset folder."""

    train: list[Flight]
    test: list[Flight]
    root: Path | None = None


@dataclass
class Scores:
    """Multi-horizon scores.

    Attributes:
        mae: Mean absolute error per horizon, ``(H,)`` per quantity: ``p`` (m),
            ``v`` (m/s), ``R`` (rad, geodesic), ``w`` (rad/s).
        n_windows: Number of windows scored.
        per_flight: Scores of each flight, by flight name, when scored over flights.
    """

    mae: dict[str, np.ndarray]
    n_windows: int
    per_flight: dict[str, "Scores"] = field(default_factory=dict)

    @property
    def simerr(self) -> dict[str, float]:
        """Simulation error: sum of the MAE over h = 1..H."""
        return {k: float(v.sum()) for k, v in self.mae.items()}

    @property
    def horizon(self) -> int:
        return len(self.mae["p"])

    def at(self, h: int) -> dict[str, float]:
        """MAE at horizon ``h`` (1-based)."""
        return {k: float(v[h - 1]) for k, v in self.mae.items()}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: MAE curves, SimErr, and the same for each flight."""
        d: dict[str, Any] = {
            "n_windows": self.n_windows,
            "horizon": self.horizon,
            "simerr": self.simerr,
            "mae": {k: [float(x) for x in v] for k, v in self.mae.items()},
        }
        if self.per_flight:
            d["per_flight"] = {n: s.to_dict() for n, s in self.per_flight.items()}
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Scores":
        return cls(
            mae={k: np.asarray(v, dtype=np.float64) for k, v in d["mae"].items()},
            n_windows=int(d["n_windows"]),
            per_flight={n: cls.from_dict(s) for n, s in d.get("per_flight", {}).items()},
        )


def load(path: str | os.PathLike, *, horizon: int = 50) -> Benchmark:
    """Load a dataset folder with ``train/`` and ``test/`` flight CSVs in the published schema.

    Every flight is validated (see :func:`nanosysid.dataio.read_flight_csv`) and must have
    at least ``horizon + 1`` rows. Flights are sorted by name.

    Raises:
        DataError: a missing folder, an empty test set, or a flight that breaks the schema.
    """
    root = Path(path)
    parts = {}
    seen: dict[str, Path] = {}
    for part in ("train", "test"):
        d = root / part
        if not d.is_dir():
            raise DataError(f"{d}: no such folder (a benchmark folder holds train/ and test/)")
        files = flight_catalog(d, any_name=True)
        for f in files:
            if f.name in seen:
                raise DataError(f"{f.path}: flight {f.name} is in both train/ and test/ (also {seen[f.name]}); a "
                                "flight scored on must not be trained on")
            seen[f.name] = f.path
        parts[part] = [read_flight_csv(f.path, min_rows=horizon + 1, name=f.name) for f in files]
    check_distinct(parts["train"] + parts["test"])
    if not parts["test"]:
        raise DataError(f"{root / 'test'}: no flight CSV files")
    return Benchmark(train=parts["train"], test=parts["test"], root=root)


def windows(flight: Flight, horizon: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All ``T - H`` evaluation windows of a flight, as strided views (no copy).

    Returns:
        ``y0 (N, 13)``, ``u (N, H, 4)`` and the targets ``y (N, H, 13)``.
    """
    if not isinstance(flight, Flight):
        raise DataError(f"windows: flight must be a Flight, got {type(flight).__name__}")
    horizon = _count(horizon, "horizon")
    T = len(flight)
    n = T - horizon
    if n < 1:
        raise DataError(f"flight {flight.name}: {T} samples, fewer than horizon + 1 = {horizon + 1}")
    check_flight(flight)
    win = np.lib.stride_tricks.sliding_window_view
    u = win(flight.u, horizon, axis=0)[:n].transpose(0, 2, 1)  # (N, H, 4)
    y = win(flight.y[1:], horizon, axis=0)[:n].transpose(0, 2, 1)  # (N, H, 13)
    return flight.y[:n], u, y


def _to_numpy(a, what: str = "predictions") -> np.ndarray:
    if hasattr(a, "detach"):
        a = a.detach().cpu().numpy()
    try:
        return np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise PredictionError(f"{what}: values that are not numbers ({e})") from None


def _count(value, name: str) -> int:
    """A positive whole number of a protocol setting (``horizon``, ``batch_size``)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{name} must be a whole number >= 1, got {value!r}")
    return int(value)


def _read_only(a: np.ndarray) -> np.ndarray:
    # a predictor gets its own copy: writing to it cannot change the flight or the targets
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


RATE_TOLERANCE = 0.01  # the share a flight's median sample period may differ from the protocol's


def check_flight(flight: Flight) -> None:
    """Refuse a flight that cannot be the truth of a score: non-finite inputs or outputs,
    quaternions off unit norm (a zero quaternion would score every rotation as exact), samples
    not at the protocol's rate (h steps would not be h x 10 ms). The message names the flight,
    the column and the sample: bad data is not the predictor's fault."""
    for arr, cols in ((flight.u, INPUT_COLUMNS), (flight.y, OUTPUT_COLUMNS)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i, c = np.argwhere(bad)[0]
            raise DataError(f"flight {flight.name}: column {cols[c]!r} is {arr[i, c]} at sample {i} "
                            f"(t = {flight.t[i]:.6g} s); the truth must be finite to be scored against")
    out = (flight.u < 0) | (flight.u > 1.5 * NO_LOAD_SPEED)
    if out.any():
        i, c = np.argwhere(out)[0]
        raise DataError(f"flight {flight.name}: column {INPUT_COLUMNS[c]!r} is {flight.u[i, c]:.6g} rad/s at sample {i}; "
                        f"a rotor speed is a magnitude below the motor's no-load speed (about {NO_LOAD_SPEED:g} rad/s): "
                        "another unit or sign?")
    norm = np.linalg.norm(flight.y[:, 6:10], axis=1)
    off = np.abs(norm - 1.0) > QUAT_NORM_TOLERANCE
    if off.any():
        i = int(np.argmax(off))
        raise DataError(f"flight {flight.name}: the quaternion (qx..qw) at sample {i} (t = {flight.t[i]:.6g} s) has "
                        f"norm {norm[i]:.4g}; the truth needs unit quaternions (within {QUAT_NORM_TOLERANCE:g})")
    if len(flight) > 1:
        steps = np.diff(flight.t)
        dt = float(np.median(steps))
        if not abs(dt / SAMPLE_PERIOD - 1) <= RATE_TOLERANCE:
            raise DataError(f"flight {flight.name}: column 't': samples {dt:.6g} s apart ({1 / dt:.4g} Hz); the "
                            f"protocol's horizons are steps of {SAMPLE_PERIOD:g} s ({1 / SAMPLE_PERIOD:g} Hz): "
                            "resample the flight first")
        # a gap, a repeat or a step back inside the flight: a window across it would be scored
        # as if its samples were 10 ms apart
        odd = np.abs(steps / SAMPLE_PERIOD - 1) > 0.5
        if odd.any():
            i = int(np.argmax(odd))
            raise DataError(f"flight {flight.name}: column 't' goes from {flight.t[i]:.6g} to {flight.t[i + 1]:.6g} s "
                            f"between samples {i} and {i + 1} (a step of {steps[i]:.4g} s, not {SAMPLE_PERIOD:g}): "
                            "split the flight at the gap or resample it")


def check_predictions(pred: np.ndarray, where: str) -> None:
    """Refuse what cannot be scored: non-finite values, and quaternions whose norm is far from 1
    (the geodesic angle of a zero quaternion would read as no error at all)."""
    bad = ~np.isfinite(pred)
    if bad.any():
        i, h, c = np.argwhere(bad)[0]
        raise PredictionError(f"{where}: the prediction is {pred[i, h, c]} at window {i}, step {h + 1}, "
                              f"output {c}; every predicted value must be finite")
    norm = np.linalg.norm(pred[..., 6:10], axis=-1)
    off = np.abs(norm - 1.0) > QUAT_NORM_TOLERANCE
    if off.any():
        i, h = np.argwhere(off)[0]
        raise PredictionError(f"{where}: the predicted quaternion at window {i}, step {h + 1} has norm "
                              f"{norm[i, h]:.4g}; a rotation needs a unit quaternion (within {QUAT_NORM_TOLERANCE:g})")


def _predicted_batches(predict: Predictor, y0: np.ndarray, u: np.ndarray, batch_size: int, flight: Flight,
                       starts: np.ndarray | None = None):
    """``(slice, prediction)`` over batches of windows, the predictions checked; the predictor
    gets read-only copies of the windows (and a timed one their start times)."""
    n, horizon, name = u.shape[0], u.shape[1], flight.name
    timed = getattr(predict, "timed", False)
    t0 = flight.t - flight.t[0]
    t0 = t0[:n] if starts is None else t0[starts]
    for s in range(0, n, batch_size):
        b = slice(s, min(s + batch_size, n))
        context = {"t0": _read_only(t0[b]), "flight": name} if timed else {}
        # a rollout is a loop over time on small tensors, whatever the predictor: one thread
        # (numerics.LOOP_THREADS) is as fast when the machine is idle and not stalled when it is busy
        with threads(LOOP_THREADS):
            pred = _to_numpy(predict(_read_only(y0[b]), _read_only(u[b]), **context), f"flight {name}: the predictor")
        if pred.shape != (b.stop - b.start, horizon, 13):
            raise PredictionError(
                f"predictor returned shape {pred.shape} on flight {name}; "
                f"expected {(b.stop - b.start, horizon, 13)}"
            )
        check_predictions(pred, f"flight {name}")
        yield b, pred


@dataclass
class Kept:
    """What the figures and recordings show of a predictor's rollouts on one flight, kept while
    it is scored so that they need not roll it out again.

    Attributes:
        last: ``(N, 13)``: row ``i`` is the prediction of sample ``i + H`` from start ``i``,
            the H-step-ahead prediction along the flight.
        paths: ``(S, H, 13)``: the whole rollouts from the starts ``0, stride, 2 stride, ..``.
        stride: Starts between two kept whole rollouts.
    """

    last: np.ndarray
    paths: np.ndarray
    stride: int

    @property
    def starts(self) -> np.ndarray:
        """The starts of :attr:`paths`, ``(S,)``."""
        return np.arange(0, len(self.last), self.stride)


def _score_flight(predict: Predictor, flight: Flight, horizon: int, batch_size: int,
                  stride: int | None = None) -> tuple[Scores, Kept | None]:
    y0, u, y = windows(flight, horizon)
    n = len(y0)
    sums = {k: np.zeros(horizon) for k in metrics.QUANTITIES}
    last, paths = (np.empty((n, 13)), []) if stride else (None, [])
    for b, pred in _predicted_batches(predict, y0, u, batch_size, flight):
        for k, e in metrics.errors(y[b], pred).items():
            sums[k] += e.sum(axis=0)
        if stride:
            last[b] = pred[:, -1]
            paths.append(pred[(-b.start) % stride::stride])
    kept = Kept(last, np.concatenate(paths), stride) if stride else None
    return Scores(mae={k: v / n for k, v in sums.items()}, n_windows=n), kept


def save_kept(kept: Mapping[str, Kept], folder: str | os.PathLike) -> None:
    """Write each flight's :class:`Kept` rollouts into ``folder`` (which must exist):
    ``<flight>.last.npy``, ``<flight>.paths.npy`` and ``kept.json`` (the stride and the flights'
    window counts). ``.npy`` files hold no time stamp: the same rollouts, the same bytes."""
    import json

    folder = Path(folder)
    for name, k in kept.items():
        np.save(folder / f"{name}.last.npy", np.ascontiguousarray(k.last))
        np.save(folder / f"{name}.paths.npy", np.ascontiguousarray(k.paths))
    index = {"stride": {n: k.stride for n, k in kept.items()}, "windows": {n: len(k.last) for n, k in kept.items()}}
    (folder / "kept.json").write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")


def load_kept(folder: str | os.PathLike, flights: Sequence[Flight], *, horizon: int, stride: int | None = None,
              stage: str = "evaluate") -> dict[str, Kept]:
    """The :class:`Kept` rollouts :func:`save_kept` wrote in ``folder``, one per flight, checked
    against the flights (their windows at ``horizon``) and ``stride`` (when given).

    Raises:
        DataError: none kept there, or kept for other flights, another horizon or stride,
            naming the folder and the ``stage`` that writes them.
    """
    import json

    folder = Path(folder)
    index_file = folder / "kept.json"
    if not index_file.is_file():
        raise DataError(f"{folder}: no kept rollouts (kept.json); the {stage} stage writes them")
    try:
        index = json.loads(index_file.read_text())
        out = {}
        for f in flights:
            n, s = len(f) - horizon, index["stride"].get(f.name)
            if index["windows"].get(f.name) != n:
                raise DataError(f"{index_file}: no rollouts of flight {f.name} at horizon {horizon} ({n} windows); "
                                f"rerun the {stage} stage")
            if stride is not None and s != stride:
                raise DataError(f"{index_file}: rollouts kept every {s} starts, not every {stride}; rerun the {stage} "
                                "stage with the same stride")
            k = Kept(np.load(folder / f"{f.name}.last.npy"), np.load(folder / f"{f.name}.paths.npy"), int(s))
            if k.last.shape != (n, 13) or k.paths.shape != (len(k.starts), horizon, 13):
                raise DataError(f"{folder}: the kept rollouts of flight {f.name} have shapes {k.last.shape} and "
                                f"{k.paths.shape}; rerun the {stage} stage")
            out[f.name] = k
    except DataError:
        raise
    except (OSError, ValueError, KeyError, AttributeError) as e:
        raise DataError(f"{folder}: kept rollouts unreadable ({e}); rerun the {stage} stage") from None
    return out


def predictions(predict: Predictor, flight: Flight, *, horizon: int = 50, batch_size: int = 8192,
                starts: np.ndarray | None = None) -> np.ndarray:
    """The predictor's open-loop rollouts on a flight, ``(N, H, 13)``: row ``i`` starts at
    sample ``starts[i]`` (every admissible start, ``0..T-H-1``, by default) and holds the
    predictions of samples ``starts[i] + 1 .. starts[i] + H``."""
    horizon, batch_size = _count(horizon, "horizon"), _count(batch_size, "batch_size")
    _check_predictor(predict, "predictions")
    y0, u, _ = windows(flight, horizon)
    if starts is not None:
        s = np.asarray(starts)
        if s.ndim != 1 or not (np.issubdtype(s.dtype, np.integer) or s.size == 0) or (s.size and (
                s.min() < 0 or s.max() >= len(y0))):
            raise ConfigError(f"predictions: starts must be whole numbers from 0 to {len(y0) - 1} (the windows of flight "
                              f"{flight.name} at horizon {horizon}), got {np.asarray(starts).ravel()[:5].tolist()}"
                              + (" ..." if np.asarray(starts).size > 5 else ""))
        y0, u = y0[s], u[s]
        starts = s
    out = np.empty((len(y0), horizon, 13))
    for b, pred in _predicted_batches(predict, y0, u, batch_size, flight, starts):
        out[b] = pred
    return out


def template_frame(predict: Predictor, flight: Flight, *, horizon: int = 50, batch_size: int = 8192):
    """A predictor's rollouts on a flight in the DataFrame layout of the nonlinear_benchmarks
    metric template (``nanodrone_error_metrics.compute_errors``): one row per sample, ``t`` and
    the measured outputs (``x`` .. ``wz``), and ``{x..wz}_pred_h{h}``, h = 1..H.

    Row ``t`` holds the prediction started at sample ``t``: ``x_pred_h{h}`` is the prediction
    of ``x`` at sample ``t + h``, from the state at ``t`` and the inputs of ``t .. t + h - 1``
    (the paper's definition, which :func:`evaluate` scores). The last ``H`` rows, where no
    whole window starts, are NaN. The template scores ``pred_h{h}`` of row ``t`` against the
    measurement of row ``t + h - 1``; ``frame[pred_columns].shift(1)`` moves each prediction
    one row down, so that the template's figures are ours.
    """
    import pandas as pd

    pred = predictions(predict, flight, horizon=horizon, batch_size=batch_size)  # (T - H, H, 13)
    T, n = len(flight), len(pred)
    cols: dict[str, np.ndarray] = {"t": flight.t}
    for j, c in enumerate(OUTPUT_COLUMNS):
        cols[c] = flight.y[:, j]
    for j, c in enumerate(OUTPUT_COLUMNS):
        for h in range(1, horizon + 1):
            col = np.full(T, np.nan)
            col[:n] = pred[:, h - 1, j]
            cols[f"{c}_pred_h{h}"] = col
    return pd.DataFrame(cols)


def write_template(predict: Predictor, flight: Flight, path: str | os.PathLike, *, horizon: int = 50) -> None:
    """:func:`template_frame` as a CSV file (written atomically)."""
    frame = template_frame(predict, flight, horizon=horizon)
    with atomic_file(path, inputs=[flight.source] if flight.source else ()) as tmp:
        frame.to_csv(tmp, index=False, float_format="%.10g", lineterminator="\n")


def _check_predictor(predict: Any, where: str) -> None:
    if not callable(predict):
        raise ConfigError(f"{where}: predict must be a predictor, a function predict(y0 (B, 13), u (B, H, 4)) -> "
                          f"(B, H, 13), got {type(predict).__name__}")


def evaluate(
    predict: Predictor, flights: Sequence[Flight], *, horizon: int = 50, batch_size: int = 8192,
    keep: int | None = None,
) -> Scores | tuple[Scores, dict[str, Kept]]:
    """Score a predictor on every window of every flight.

    The top-level MAE is the mean of the per-flight MAE curves, as the paper averages
    over the three Melon runs; ``per_flight`` holds each flight's own scores.

    ``keep``: also return, by flight name, the rollouts the figures and recordings show
    (:class:`Kept`, whole rollouts every ``keep`` starts), taken from the same rollouts.
    """
    flights = flight_list(flights, "evaluate")
    if not flights:
        raise DataError("evaluate: no flights given")
    _check_predictor(predict, "evaluate")
    horizon, batch_size = _count(horizon, "horizon"), _count(batch_size, "batch_size")
    if keep is not None:
        keep = _count(keep, "keep")
    names = [f.name for f in flights]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise DataError(f"evaluate: flight name(s) {', '.join(twice)} given more than once; each flight is scored "
                        "under its name, so one would be left out")
    both = {f.name: _score_flight(predict, f, horizon, batch_size, keep) for f in flights}
    per = {n: s for n, (s, _) in both.items()}
    mae = {k: np.mean([s.mae[k] for s in per.values()], axis=0) for k in metrics.QUANTITIES}
    scores = Scores(mae=mae, n_windows=sum(s.n_windows for s in per.values()), per_flight=per)
    return scores if keep is None else (scores, {n: k for n, (_, k) in both.items()})


def score(y_true, y_pred) -> Scores:
    """Scores of predictions ``(N, H, 13)`` against truth ``(N, H, 13)``, pooled over windows."""
    y_true, y_pred = _to_numpy(y_true, "score: y_true"), _to_numpy(y_pred, "score: y_pred")
    if y_true.ndim != 3 or y_true.shape != y_pred.shape or y_true.shape[-1] != 13 or not y_true.size:
        raise PredictionError(f"expected two (N, H, 13) arrays with N, H >= 1, got {y_true.shape} and {y_pred.shape}")
    check_predictions(y_pred, "score")
    if not np.isfinite(y_true).all():
        i, h, c = np.argwhere(~np.isfinite(y_true))[0]
        raise DataError(f"score: the truth is {y_true[i, h, c]} at window {i}, step {h + 1}, output {c}; "
                        "the truth must be finite")
    tnorm = np.linalg.norm(y_true[..., 6:10], axis=-1)
    if (np.abs(tnorm - 1.0) > QUAT_NORM_TOLERANCE).any():
        i, h = np.argwhere(np.abs(tnorm - 1.0) > QUAT_NORM_TOLERANCE)[0]
        raise DataError(f"score: the true quaternion at window {i}, step {h + 1} has norm {tnorm[i, h]:.4g}; "
                        f"the truth needs unit quaternions (within {QUAT_NORM_TOLERANCE:g})")
    errs = metrics.errors(y_true, y_pred)
    return Scores(mae={k: e.mean(axis=0) for k, e in errs.items()}, n_windows=len(y_true))
