"""The generic sparse fit: a disagreement no named effect explains, captured by a few products
of physically meaningful signals (:data:`nanosysid.effects.TERM_SIGNALS`: body velocity, body
rates, thrust, height).

The terms are pysindy's polynomial library of those signals, and the sparse regression is
pysindy's sequentially thresholded least squares (STLSQ) on unit-norm columns. Samples are
kept only as far apart as the residual decorrelates (the smoothing filter and slow
disturbances correlate neighbours), and the residual is scaled by its own spread, so the scatter
of a normalised coefficient is about one and the threshold is a z-score: :data:`THRESHOLD`,
about the two-sided 1 % level for the few hundred terms and channels tried.
"""

from __future__ import annotations

from typing import Sequence

import itertools
import warnings

import numpy as np

from nanosysid.effects import CHANNELS, TERM_SIGNALS, term_name

__all__ = ["TermLibrary", "sparse_fit", "heldout_gain", "decorrelation", "THRESHOLD", "terms_of"]

THRESHOLD = 4.0


class TermLibrary:
    """pysindy's polynomial library of the signals, each centred and scaled first (products of
    raw signals are nearly collinear: z and z², T and T W), with the way back to raw products.

    Args:
        signals: ``(N, S)`` samples of :data:`TERM_SIGNALS`, which fix the centres and scales.
    """

    def __init__(self, signals: np.ndarray, degree: int = 2) -> None:
        import pysindy as ps  # here, not above: every predictor imports this package, few fit

        self.mean = signals.mean(axis=0)
        self.scale = np.where(signals.std(axis=0) > 0, signals.std(axis=0), 1.0)
        self.lib = ps.PolynomialLibrary(degree=degree, include_bias=True)
        self.lib.fit(self._standard(signals[:2]))
        self.powers = np.asarray(self.lib.powers_)
        names = list(TERM_SIGNALS)
        self.names = ["*".join(n for n, p in zip(names, pw) for _ in range(int(p))) or "1" for pw in self.powers]
        self.labels = ["·".join(f"({n}~)" + ("²" if p == 2 else "") for n, p in zip(names, pw) if p) or "1"
                       for pw in self.powers]

    def _standard(self, signals: np.ndarray) -> np.ndarray:
        return (signals - self.mean) / self.scale

    def __call__(self, signals: np.ndarray) -> np.ndarray:
        """The terms of signals ``(N, S)``, ``(N, M)``."""
        return np.asarray(self.lib.transform(self._standard(signals)))

    def raw(self, coef: np.ndarray) -> np.ndarray:
        """Coefficients ``(M,)`` of the standardised terms as coefficients of the raw products
        (the same function): each ``Π (x_i - m_i) / s_i`` expanded."""
        out = np.zeros(len(self.powers))
        index = {tuple(p): k for k, p in enumerate(self.powers)}
        for k, pw in enumerate(self.powers):
            if coef[k] == 0:
                continue
            factors = [i for i, p in enumerate(pw) for _ in range(int(p))]
            c = coef[k] / np.prod([self.scale[i] for i in factors]) if factors else coef[k]
            # expand prod (x_i - m_i) over the subsets of factors kept as x_i
            for keep in itertools.product((0, 1), repeat=len(factors)):
                p = np.zeros(len(pw), dtype=int)
                term = c
                for f, kf in zip(factors, keep):
                    if kf:
                        p[f] += 1
                    else:
                        term *= -self.mean[f]
                out[index[tuple(p)]] += term
        return out


def decorrelation(y: np.ndarray, level: float = 0.2, max_lag: int = 200) -> int:
    """The lag (samples) beyond which every column of ``y (N, C)`` is correlated by less than
    ``level`` with itself: samples that far apart count as independent.

    The first lag ``k`` (1 to ``min(max_lag, N // 4) - 1``, that last if none) at which every
    column's ``sum(y[k:] y[:-k]) / sum(y^2)`` (``y`` centred) is below ``level``. The first
    :data:`_DIRECT` lags are summed directly; the sums of the others come at once from one
    transform, and where one lies within :data:`_SCREEN` of ``level`` its lag is summed directly
    too, so the lag is the direct sums' to the last bit."""
    y = y - y.mean(axis=0)
    var = np.maximum((y ** 2).sum(axis=0), 1e-300)
    last = min(max_lag, len(y) // 4)

    def below(k: int) -> bool:
        return bool(np.all((y[k:] * y[:-k]).sum(axis=0) / var < level))

    for k in range(1, min(last, _DIRECT)):
        if below(k):
            return k
    if last <= _DIRECT:
        return max(last - 1, 1)
    n = len(y) + last  # zero padding past the largest lag: no wrap-around
    spectrum = np.fft.rfft(y, n=n, axis=0)
    screened = np.fft.irfft(spectrum * spectrum.conj(), n=n, axis=0)[:last] / var
    for k in range(_DIRECT, last):
        r = screened[k]
        if np.all(r < level - _SCREEN):
            return k
        if np.any(r >= level + _SCREEN):
            continue
        if below(k):
            return k
    return last - 1


# lags summed directly before the transform pays (a short lag is found in a few sums)
_DIRECT = 8
# the transform's error on a correlation (a few 1e-15 for a million samples) is far below it
_SCREEN = 1e-6


def sparse_fit(theta: np.ndarray, y: np.ndarray, *, threshold: float = THRESHOLD, stride: int | None = None) -> np.ndarray:
    """Sparse coefficients ``(C, M)`` of ``y (N, C) ≈ theta (N, M) @ coef.T``.

    Fitted on samples ``stride`` apart (by default the residual's own decorrelation lag, so they
    count as independent) with each column of ``y`` in units of its own spread: a term stays
    when its coefficient on a unit-norm column is ``threshold`` times the scatter it must stand
    out of."""
    import pysindy as ps
    import sklearn

    stride = stride or decorrelation(y)
    scale = np.maximum(y.std(axis=0), 1e-300)
    opt = ps.STLSQ(threshold=threshold, alpha=1e-9, normalize_columns=True, unbias=True, max_iter=20)
    # sklearn's checks of the arguments pysindy passes, thousands of times a discovery: skipped
    with warnings.catch_warnings(), sklearn.config_context(skip_parameter_validation=True):
        warnings.simplefilter("ignore", UserWarning)  # "eliminated all coefficients": nothing to capture
        opt.fit(theta[::stride], y[::stride] / scale)
    return np.asarray(opt.coef_).reshape(y.shape[1], theta.shape[1]) * scale[:, None]


def heldout_gain(theta: np.ndarray, y: np.ndarray, blocks: np.ndarray, fold: np.ndarray, *,
                 threshold: float = THRESHOLD, stride: int | None = None) -> np.ndarray:
    """Each block's held-out drop of the SSE of ``y (N, C)`` by the sparse fit, ``(B, C)``:
    fitted (terms chosen and coefficients) on the other folds, ``fold[b]`` the fold of block ``b``."""
    B = int(blocks.max()) + 1
    base = np.zeros((B, y.shape[1]))
    np.add.at(base, blocks, y ** 2)
    left = np.zeros_like(base)
    sample_fold = fold[blocks]
    stride = stride or decorrelation(y)
    for k in np.unique(fold):
        train = sample_fold != k
        coef = sparse_fit(theta[train], y[train], threshold=threshold, stride=stride)
        test = ~train
        np.add.at(left, blocks[test], (y[test] - theta[test] @ coef.T) ** 2)
    return base - left


def terms_of(coef: np.ndarray, library: TermLibrary, channels: Sequence[int], weights: np.ndarray
             ) -> tuple[dict[str, float], dict[str, float]]:
    """The kept terms: as library names ``term:<channel>:<product>`` of raw products ->
    coefficient in physical units (what the augmented model adds), and as the standardised terms
    the fit chose (``<channel>: (v_x~)·(w_z~)``, ``~`` centred and scaled) -> coefficient in N or N m
    (what a reader reads). ``coef`` was fitted on the residual times ``weights``."""
    raw, chosen = {}, {}
    for row, c in zip(coef, channels):
        for m in np.flatnonzero(row):
            chosen[f"{CHANNELS[c]}: {library.labels[m]}"] = float(row[m] / weights[c])
        r = library.raw(row) / weights[c]
        for m in np.flatnonzero(r):
            raw[term_name(CHANNELS[c], library.names[m])] = float(r[m])
    return raw, chosen
