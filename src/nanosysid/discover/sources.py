"""What a disagreement that no function of the state explains is a function of: the rotor
speeds' history, the battery, or time.

The drone flies in closed loop: the controller answers a disturbance of its own time through
the very rotor speeds the entries' columns are made of, so a column of the rotor speeds'
history (:data:`nanosysid.effects.SLOW_TIMES`) fits a disturbance as well as a real lag. What
tells them apart is the reference. Two runs of one reference ask the rotors for nearly the same
speeds, while a disturbance is a new realisation every flight: the partner run's columns are an
instrument, correlated with what the reference makes of a run's columns and independent of the
run's own disturbance (:func:`reference_check`). Likewise, a residual that repeats between runs
of one reference is a function of the reference (the input history or a state signal the
library lacks); one that does not is a function of time (:func:`source`).

Runs of one reference are found in the data (:func:`reference_pairs`): flights of one
trajectory whose positions, time for time, agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from nanosysid.dataio import Flight
from nanosysid.discover.stats import half_width, jackknife, pvalue

__all__ = ["reference_pairs", "Pairs", "reference_check", "source", "SOURCES", "REPEATS", "SAME_REFERENCE"]

# two flights fly one reference when their positions, time for time, differ by less than this
# share of the positions' own spread (RMS, over the time both flew)
SAME_REFERENCE = 0.35
# the most the instrumental estimate of a history entry's size may exceed the least-squares one
AGREE = 1.5
# the least share of what an entry of the rotor speeds' history fits that must repeat with the
# reference (the upper end of the instrumental slope's interval): a lag repeats whole; in closed
# loop its columns also carry the controller's answer to every disturbance and the recorded
# speeds' noise, which do not, and a few milliseconds' residual delay, which repeats in part
HISTORY_REPEAT = 0.8
# a residual that repeats between runs of one reference is a function of the reference: of the
# input history or of a state signal the library lacks
SOURCES = ("the reference", "time", "undecided")
REPEATS = SOURCES[0]


@dataclass
class Pairs:
    """Runs of one reference, sample by sample.

    Attributes:
        partners: Per flight, the index of its partner (the most alike run of its reference), or -1.
        index: Per sample of the concatenated regression data, the sample of its partner at the
            same time in the concatenated data, or -1 (no partner, or beyond its end).
        agreement: Per pair ``(i, j)``, the RMS position difference over the positions' spread.
    """

    partners: list[int]
    index: np.ndarray
    agreement: dict[tuple[int, int], float]

    @property
    def any(self) -> bool:
        return bool(np.any(self.index >= 0))

    def described(self, names: Sequence[str]) -> str:
        pairs = sorted({tuple(sorted((i, j))) for i, j in enumerate(self.partners) if j >= 0})
        return ", ".join(f"{names[i]} / {names[j]}" for i, j in pairs) or "none"


def reference_pairs(flights: Sequence[Flight], times: Sequence[np.ndarray]) -> Pairs:
    """Each flight's partner: the flight of the same trajectory whose positions agree best with
    its own, time for time, where they agree within :data:`SAME_REFERENCE`; and, for every
    sample at the times ``times`` (each flight's regression samples), its partner's sample."""
    n = len(flights)
    agreement: dict[tuple[int, int], float] = {}
    partners = [-1] * n
    for i, f in enumerate(flights):
        best = (SAME_REFERENCE, -1)
        for j, g in enumerate(flights):
            if j == i or g.trajectory != f.trajectory:
                continue
            m = min(len(f), len(g))
            if m < 10:
                continue
            a, b = f.y[:m, 0:3], g.y[:m, 0:3]
            spread = np.sqrt(np.mean(np.sum((a - a.mean(axis=0)) ** 2, axis=1)))
            diff = np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))) / max(spread, 1e-9)
            agreement[(i, j)] = float(diff)
            if diff < best[0]:
                best = (diff, j)
        partners[i] = best[1]
    starts = np.cumsum([0] + [len(t) for t in times])
    index = np.full(starts[-1], -1, dtype=int)
    for i, j in enumerate(partners):
        if j < 0:
            continue
        ti, tj = times[i], times[j]
        k = np.searchsorted(tj, ti - 1e-9)
        ok = (k < len(tj)) & (np.abs(tj[np.minimum(k, len(tj) - 1)] - ti) < 1e-6)
        index[starts[i]:starts[i + 1]][ok] = starts[j] + k[ok]
    return Pairs(partners, index, agreement)


def reference_check(contribution: np.ndarray, residual: np.ndarray, pairs: Pairs, blocks: np.ndarray,
                    folds: np.ndarray, level: float = 0.95) -> dict[str, Any]:
    """Whether an entry's fitted contribution ``(N, 6)`` (weighted) is what it says, or the
    controller's answer to a disturbance: the instrumental-variable slope of the residual it
    was fitted to ``(N, 6)`` on the contribution, the partner run's contribution at the same
    time the instrument. A real effect gives a slope near 1 (its contribution repeats with the
    reference); a disturbance that the contribution only follows gives 0. The interval is the jackknife over the folds of blocks (Student's t).

    The slope is also the instrumental estimate of the entry's size over the least-squares one:
    above :data:`AGREE` times it, least squares has fitted less than what repeats with the
    reference (a biased correction beside it, or the controller's answer to a disturbance, pulls
    its columns), so its coefficient is not the effect's either.

    Returns ``{"checked", "slope", "ci", "samples", "holds"}``; ``holds`` is False when the
    interval lies below one half (less than half of what the entry fits repeats between runs of
    one reference) or the slope is above :data:`AGREE` (the two estimates disagree by more than
    half)."""
    ok = pairs.index >= 0
    if ok.sum() < 100:
        return {"checked": False, "holds": True, "samples": int(ok.sum())}
    z = np.zeros_like(contribution)
    z[ok] = contribution[pairs.index[ok]]
    num = np.bincount(blocks, weights=(z * residual).sum(axis=1), minlength=blocks.max() + 1)
    den = np.bincount(blocks, weights=(z * contribution).sum(axis=1), minlength=blocks.max() + 1)
    k = int(folds.max()) + 1
    slope = float(num.sum() / den.sum()) if den.sum() > 0 else 0.0
    drops = []
    for f in range(k):
        keep = folds != f
        d = den[keep].sum()
        drops.append(num[keep].sum() / d if d > 0 else 0.0)
    se = float(jackknife(np.asarray(drops)[:, None])[0])
    half = half_width(se, k, level)
    lo, hi = slope - half, slope + half
    return {"checked": True, "slope": slope, "ci": (lo, hi), "samples": int(ok.sum()),
            "holds": bool(hi >= 0.5 and slope <= AGREE)}


def source(left: np.ndarray, pairs: Pairs, blocks: np.ndarray, alpha: float,
           flight: np.ndarray | None = None) -> dict[str, Any]:
    """What a residual ``left (N,)`` (in noise floors) that no function of the state explains is
    a function of: the share of its power above the noise that repeats between runs of one
    reference (the mean product of a sample and its partner's over the mean square less the
    noise's), tested block by block (one-sided signed-rank test that the products lean
    positive). Most of it repeats, significantly: a function of the reference (the input history,
    or a state signal the library lacks); less than half does, with runs to compare: a function of
    time (the share that repeats is said: a biased coefficient leaves a part that follows the
    reference); no runs of one reference: undecided. With ``flight (N,)``, each sample's flight,
    the share is also given with each flight's own mean removed (``within_share``): runs of one
    reference flown back to back can share a constant of the flight (the vehicle as it was),
    which repeats between them without being a function of the reference."""
    ok = pairs.index >= 0
    if ok.sum() < 100:
        return {"source": SOURCES[2], "why": "no two runs of one reference to compare"}
    prod = np.zeros(len(left))
    prod[ok] = left[ok] * left[pairs.index[ok]]
    per_block = np.bincount(blocks[ok], weights=prod[ok], minlength=blocks.max() + 1)
    used = np.bincount(blocks[ok], minlength=blocks.max() + 1) > 0
    z, p = pvalue(per_block[used])
    # of the power above the noise (the residual is in noise floors: the noise's mean square is 1)
    excess = max(float(np.mean(left[ok] ** 2)) - 1.0, 1e-12)
    share = float(np.mean(prod[ok]) / excess)
    repeats = p <= alpha and share >= 0.5
    out = {"source": SOURCES[0] if repeats else SOURCES[1], "repeat_share": share, "z": z, "p": p,
           "blocks": int(used.sum()), "samples": int(ok.sum())}
    if flight is not None:
        within = left - (np.bincount(flight, weights=left) / np.bincount(flight))[flight]
        out["within_share"] = float(np.mean(within[ok] * within[pairs.index[ok]]) / excess)
    return out
