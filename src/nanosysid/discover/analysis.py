"""Where the nominal model and the measurements disagree, before and after the named effects:
per channel, per flight regime, per frequency band, and in the benchmark's rollouts."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import torch

from nanosysid import protocol, so3
from nanosysid.dataio import Flight
from nanosysid.effects import CHANNELS
from nanosysid.discover.fit import EDGE, flight_data
from nanosysid.discover.model import integrating

__all__ = ["disagreement", "REGIMES", "BANDS"]

BANDS = ((0.0, 1.0), (1.0, 5.0), (5.0, 15.0))  # Hz


def _regime_variables(f: Flight) -> dict[str, np.ndarray]:
    """Speed (m/s), tilt (deg), throttle (ΣΩ² over its mean) and rotor-speed rate (rad/s²)."""
    R = so3.quat_to_rotmat(torch.from_numpy(np.ascontiguousarray(f.y[:, 6:10]))).numpy()
    om2 = (f.u ** 2).sum(axis=1)
    dt = float(np.median(np.diff(f.t)))
    return {"speed [m/s]": np.linalg.norm(f.y[:, 3:6], axis=1),
            "tilt [deg]": np.degrees(np.arccos(np.clip(R[:, 2, 2], -1, 1))),
            "throttle [ΣΩ² / mean]": om2 / om2.mean(),
            "rotor-speed rate [rad/s²]": np.abs(np.gradient(f.u, dt, axis=0)).mean(axis=1)}


REGIMES = ("speed [m/s]", "tilt [deg]", "throttle [ΣΩ² / mean]", "rotor-speed rate [rad/s²]")


def _explained(data, names, theta, generic_fits, lib) -> list[np.ndarray]:
    """Per flight, the wrench ``(T, 6)`` the fitted entries and generic terms add."""
    out = []
    for d in data:
        X = np.concatenate([d.features[n] for n in names], axis=-1)  # (T, 6, P)
        w = X @ theta
        if generic_fits:
            terms = lib(d.terms)
            for c, coef in generic_fits:
                w[:, c] += terms @ coef
        out.append(w)
    return out


def _rms(a: np.ndarray) -> list[float]:
    return [float(x) for x in np.sqrt((a ** 2).mean(axis=0))]


def disagreement(result, search, names: list[str], theta: np.ndarray, delay: float, test_flights: Sequence[Flight],
                 *, generic_fits=(), horizon: int, batch_size: int, partners: Sequence[int] = ()) -> dict[str, Any]:
    """Tables (and the data of the report's figures) of where the models disagree, in N and N m
    beside each channel's noise floor; ``partners``: per training flight, the index of its run of
    the same reference (:func:`nanosysid.discover.sources.reference_pairs`), or -1."""
    train = search.data(delay)
    lib = search.terms(delay)[0] if generic_fits else None
    test = [flight_data(f, search.vehicle, delay, window=search.window, order=search.order,
                         lag_in_k_f=search.lag_in_k_f) for f in test_flights]
    # "before" is the nominal model as given (its k_F and k_M not refitted): the residual of delay 0
    nominal = {"train": [d.r for d in search.data(0.0)],
               "test": [flight_data(f, search.vehicle, 0.0, window=search.window, order=search.order).r
                        for f in test_flights]}
    out: dict[str, Any] = {"channels": list(CHANNELS), "noise": [float(x) for x in result.noise]}
    res, left = {}, {}
    for part, data in (("test", test), ("train", train)):
        left[part] = [d.r - e for d, e in zip(data, _explained(data, names, theta, generic_fits, lib))]
        b, a = np.concatenate(nominal[part]), np.concatenate(left[part])
        res[part] = (b, a)
        out[f"rms_{part}"] = {"before": _rms(b), "after": _rms(a)}
    b, a = res["train"]
    dt = float(np.median(np.diff(search.flights[0].t)))
    # a constant of each flight (where the vehicle changes between flights): each training flight's mean residual
    out["flight_means"] = {"flights": [f.name for f in search.flights], "dt": dt, "partners": list(partners),
                           "before": [[float(x) for x in r.mean(axis=0)] for r in nominal["train"]],
                           "after": [[float(x) for x in r.mean(axis=0)] for r in left["train"]]}
    # which channel's disagreement costs the benchmark most: the nominal model's rollouts on the
    # test flights, given each channel's measured residual as a known extra wrench
    out["rollouts"] = _rollout_shares(result, search, test_flights, horizon, batch_size)
    # regimes of the channels that carry the largest share of the SimErr, on the training flights:
    # RMS of each channel per quartile of each variable
    shares = {c: sum(1 - r[k] / out["rollouts"]["nominal"][k] for k in r)
              for c, r in out["rollouts"]["with_measured_channel"].items()}
    out["regime_channels"] = sorted(CHANNELS, key=lambda c: -shares[c])[:2]
    var = {k: np.concatenate([v[EDGE:-EDGE] for v in (_regime_variables(f)[k] for f in search.flights)])
           for k in REGIMES}
    regimes = {}
    for k, x in var.items():
        edges = np.quantile(x, [0, 0.25, 0.5, 0.75, 1.0])
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, 3)
        regimes[k] = {"edges": [float(e) for e in edges],
                      "before": [_rms(b[idx == i]) for i in range(4)], "after": [_rms(a[idx == i]) for i in range(4)]}
    out["regimes"] = regimes
    # frequency bands: each channel's residual power per band, before and after
    from scipy.signal import welch  # here: scipy.signal costs 0.6 s, and every predictor imports the package

    bands, spectra = {}, {}
    for label, arr in (("before", b), ("after", a)):
        freq, psd = welch(arr, fs=1 / dt, nperseg=256, axis=0)
        df = freq[1] - freq[0]
        bands[label] = [[float(psd[(freq >= lo) & (freq < hi), c].sum() * df) for c in range(6)] for lo, hi in BANDS]
        keep = freq <= BANDS[-1][1]
        spectra["freq"] = [float(x) for x in freq[keep]]
        spectra[label] = [[float(x) for x in psd[keep, c]] for c in range(6)]
    out["bands"] = {"edges": [list(bd) for bd in BANDS], **bands}
    out["spectra"] = spectra
    out["predictable"], fits = predictable(search, delay, a)
    # the data's limit in the benchmark: the augmented model, its torque equation integrated about
    # every axis (about a held axis a torque moves nothing), given on the test flights every part
    # of the residual it leaves that the measured signals predict (fitted on the training flights)
    lib_all = search.terms(delay)[0]
    extra = []
    for d in test:
        X = _limit_columns(lib_all, d)
        w = np.zeros((len(d.r) + 2 * EDGE, 6))
        w[EDGE:-EDGE] = np.column_stack([X[c][:, keep] @ coef for c, (keep, coef) in enumerate(fits)])
        extra.append(w)
    out["limit_simerr"] = _with_extra(integrating(result.model), test_flights, extra, horizon, batch_size)
    out["samples"] = {"train": int(len(b)), "test": int(sum(len(d.r) for d in test))}
    out["scatter"] = _scatter(result, train, names, theta, generic_fits, lib, var, 1 / dt)
    return out


def predictable(search, delay: float, left: np.ndarray) -> dict[str, Any]:
    """How much of the residual ``left (N, 6)`` (N, N m) that discovery leaves any function of
    the measured signals could still predict: per channel, the held-out share of its power that
    a least-squares fit (block folds, as every score of discovery) explains with the generic
    terms of the state (products up to degree two), the rotor speeds' history (the slow
    actuation's columns at every time constant) and the battery voltage's (where measured).
    In closed loop the rotor speeds carry the controller's answer to a disturbance too, so the
    share is an upper bound of what a model of the measured signals can reach; what it leaves is
    unpredictable from them. Also returns, per channel, the columns kept and their coefficients
    fitted on every training block."""
    data = search.data(delay)
    lib = search.terms(delay)[0]
    per = [_limit_columns(lib, d) for d in data]
    g = search.grams(delay)
    fold = g.fold[search.blocks]
    out: dict[str, Any] = {"share": [], "power": []}
    fits = []
    for c in range(6):
        X = np.concatenate([p[c] for p in per])
        keep = np.any(X != 0, axis=0)
        X = X[:, keep]
        y = left[:, c]
        scale = np.maximum(np.abs(X).max(axis=0), 1e-300)

        def fit(rows):
            return np.linalg.lstsq(X[rows] / scale, y[rows], rcond=1e-10)[0] / scale

        sse = 0.0
        for k in range(g.folds):
            tr, te = fold != k, fold == k
            sse += float(((y[te] - X[te] @ fit(tr)) ** 2).sum())
        power = float((y ** 2).sum())
        out["share"].append(max(0.0, 1.0 - sse / power) if power > 0 else 0.0)
        out["power"].append(float(np.sqrt(power / len(y))))
        fits.append((keep, fit(slice(None))))
    out["battery"] = bool(any(np.any(d.features["battery_thrust"] != 0) for d in data))
    return out, fits


def _limit_columns(lib, d) -> list[np.ndarray]:
    """Per channel, the columns of the data's limit on one flight's regression data ``d``: the
    generic terms of the state, the slow actuation's and the battery's columns of the channel."""
    terms = lib(d.terms)
    return [np.column_stack([terms, d.features["slow_actuation"][:, c], d.features["battery_thrust"][:, c]])
            for c in range(6)]


def _with_extra(model, flights, extra, horizon, batch_size) -> dict[str, float] | None:
    """SimErr of ``model`` on ``flights`` given a known extra body wrench ``(T, 6)`` per flight
    (None where the rollouts do not stay finite)."""
    sums = {k: [] for k in ("p", "v", "R", "w")}
    for f, r in zip(flights, extra):
        y0, u, y = protocol.windows(f, horizon)
        ex = np.lib.stride_tricks.sliding_window_view(r, horizon, axis=0)[:len(y0)].transpose(0, 2, 1)
        pred = np.concatenate([model(y0[s:s + batch_size], u[s:s + batch_size], ex[s:s + batch_size])
                               for s in range(0, len(y0), batch_size)])
        if not np.all(np.isfinite(pred)):
            return None  # the fitted rest drives the rollouts away: no limit to report
        for k, v in protocol.score(y, pred).simerr.items():
            sums[k].append(v)
    # the mean of the flights' curves, as protocol.evaluate averages the test flights
    return {k: float(np.mean(v)) for k, v in sums.items()}


def _rollout_shares(result, search, flights, horizon, batch_size) -> dict[str, Any]:
    nominal = result.nominal
    # the nominal model reads the rotor speeds as recorded: its residual is the undelayed one
    residual = [flight_data(f, search.vehicle, 0.0, window=search.window, order=search.order).r for f in flights]
    rows = {}
    for c, channel in enumerate(CHANNELS):
        sums = {k: [] for k in ("p", "v", "R", "w")}
        for f, res in zip(flights, residual):
            r = np.zeros((len(f), 6))
            r[EDGE:-EDGE, c] = res[:, c]
            y0, u, y = protocol.windows(f, horizon)
            extra = np.lib.stride_tricks.sliding_window_view(r, horizon, axis=0)[:len(y0)].transpose(0, 2, 1)
            pred = np.concatenate([nominal(y0[s:s + batch_size], u[s:s + batch_size], extra[s:s + batch_size])
                                   for s in range(0, len(y0), batch_size)])
            s = protocol.score(y, pred)
            for k in sums:
                sums[k].append(s.simerr[k])
        rows[channel] = {k: float(np.mean(v)) for k, v in sums.items()}
    return {"nominal": result.before.simerr, "with_measured_channel": rows}


def _where(x: np.ndarray, var: dict[str, np.ndarray], fs: float) -> tuple[str, str]:
    """The flight regime (the quartile of one regime variable) and the frequency band where a
    signal ``x (N,)`` is largest."""
    best, label = 0.0, ""
    for k, v in var.items():
        edges = np.quantile(v, [0, 0.25, 0.5, 0.75, 1.0])
        idx = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, 3)
        rms = np.array([np.sqrt((x[idx == i] ** 2).mean()) for i in range(4)])
        contrast = rms.max() / max(rms.min(), 1e-30)
        if contrast > best:
            i = int(rms.argmax())
            best, label = contrast, f"{k} {edges[i]:.3g} – {edges[i + 1]:.3g} ({contrast:.1f}x the quietest quartile)"
    from scipy.signal import welch

    freq, psd = welch(x, fs=fs, nperseg=256)
    power = [psd[(freq >= lo) & (freq < hi)].sum() for lo, hi in BANDS]
    b = int(np.argmax(power))
    band = f"{BANDS[b][0]:g}–{BANDS[b][1]:g} Hz ({100 * power[b] / max(sum(power), 1e-300):.0f} % of its power)"
    return label, band


def _scatter(result, train, names, theta, generic_fits, lib, var, fs, n_max: int = 4000) -> dict[str, Any]:
    """For each finding, in the channel it acts on most: its fitted contribution, the residual
    with everything else fitted removed, and what is left after all of it (N or N m); and the
    regime and band where the contribution is largest (into the finding's evidence)."""
    offs, k = {}, 0
    for nm in names:
        P = train[0].features[nm].shape[-1]
        offs[nm] = slice(k, k + P)
        k += P
    R = np.concatenate([d.r for d in train])
    total = np.concatenate(_explained(train, names, theta, generic_fits, lib))
    step = max(1, len(R) // n_max)
    out = {}
    terms = np.concatenate([lib(d.terms) for d in train]) if generic_fits else None
    for i, f in enumerate(result.findings):
        contrib = np.zeros_like(R)
        if f.entry in offs:
            X = np.concatenate([d.features[f.entry] for d in train])
            contrib = X @ theta[offs[f.entry]]
        elif f.verdict == "unnamed" and not f.evidence.get("saturated"):
            for c, coef in generic_fits:
                if CHANNELS[c] in f.channels:
                    contrib[:, c] = terms @ coef
        else:
            continue
        ch = int(np.argmax(contrib.std(axis=0) / np.asarray(result.noise)))
        label = f.entry or f"unnamed ({', '.join(f.channels)})"
        f.evidence["regime"], f.evidence["band"] = _where(contrib[:, ch], var, fs)
        out[label] = {"verdict": f.verdict, "channel": CHANNELS[ch], "noise": float(result.noise[ch]),
                      "model": contrib[::step, ch].tolist(), "residual_after": (R - total)[::step, ch].tolist(),
                      "residual_others_removed": (R - total + contrib)[::step, ch].tolist()}
    return out
