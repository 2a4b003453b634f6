"""Discovery's candidate search: forward selection over the library, one round at a time, and
the pruning of the entries that only correlate with a disagreement outside the library.

Each round adds every candidate not yet chosen to the chosen ones and measures its held-out
gain block by block; the one-sided signed-rank test (Bonferroni over the round's candidates),
its size in noise floors and its physical signs make it eligible; the eligible candidate with the
largest gain is chosen, and the eligible ones on its channels that it does not beat
significantly are its alternatives. The rotor-speed delay is searched over a grid nested inside
the folds, and its value read between the grid's points.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from nanosysid.discover import generic
from nanosysid.discover.records import Candidate, Pick
from nanosysid.discover.fit import COLUMN_ENTRIES
from nanosysid.discover.search import Search, channels_of
from nanosysid.discover.sources import HISTORY_REPEAT, Pairs, reference_check
from nanosysid.discover.stats import hodges_lehmann, jackknife, pvalue
from nanosysid.effects import CHANNELS, DELAY, LIBRARY, NOMINAL, entry, split_coefficients

__all__ = ["Selection", "select", "prune", "check_reference"]


@dataclass
class Selection:
    """The selection's outcome: every round's candidates (best held-out gain first), the picks
    in order, the entries chosen and the rotor-speed delay (s)."""

    rounds: list[list[Candidate]]
    picks: list[Pick]
    chosen: list[str]
    delay: float
    dropped: list[Pick] = field(default_factory=list)


def _round(search: Search, chosen: list[str], delay: float, current: np.ndarray, delays: Sequence[float], *,
           alpha: float, floor: float, total: float) -> list[Candidate]:
    """Every candidate not yet chosen, added to ``chosen`` and tested against ``current`` (the
    held-out sum of squares per block without it)."""
    tried: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    g = search.grams(delay)
    for name, c in LIBRARY.items():
        if name in chosen or c is DELAY:
            continue
        tried[name] = g.heldout(search.cols(chosen + [name]))
    if delay == 0.0 and delays:
        sse, per_fold = search.nested_delay(chosen, (0.0,) + delays)
        tried[DELAY.name] = (sse, per_fold[:, None])
    K, n_samples = len(tried), len(search.blocks)
    out = []
    for name, (sse, thetas) in tried.items():
        gains = current - sse
        z, p = pvalue(gains)
        size = float(np.sqrt(max(gains.sum(), 0.0) / n_samples))
        plausible = _signs_ok(name, thetas, search, chosen)
        p = min(1.0, p * K)
        out.append(Candidate(name, sse, thetas, gains, z, p, size, float(gains.sum() / total), bool(plausible),
                             bool(p <= alpha and size >= floor and plausible)))
    return out


def select(search: Search, delays: Sequence[float], *, alpha: float, floor: float, total: float) -> Selection:
    """Forward selection until no candidate is eligible."""
    chosen: list[str] = []
    delay = 0.0
    current, _ = search.grams(0.0).heldout(search.cols(chosen))
    rounds: list[list[Candidate]] = []
    picks: list[Pick] = []
    while True:
        candidates = _round(search, chosen, delay, current, delays, alpha=alpha, floor=floor, total=total)
        rounds.append(sorted(candidates, key=lambda c: -c.heldout_gain))
        eligible = [c for c in candidates if c.eligible]
        if not eligible:
            break
        best = max(eligible, key=lambda c: c.gains.sum())
        # the alternatives: eligible entries acting on the same channels that do not explain
        # significantly less (the delay acts on every channel, through the rotor speeds)
        mine = search.touched(best.name)
        alts = [c.name for c in eligible if c is not best and search.touched(c.name) & mine
                and pvalue(c.sse - best.sse)[1] > alpha]
        picks.append(Pick(best, len(rounds), alts, [c.name for c in eligible if c is not best]))
        if best.name == DELAY.name:
            delay = _best_delay(search, chosen, (0.0,) + tuple(delays))
            current, _ = search.grams(delay).heldout(search.cols(chosen))
        else:
            chosen.append(best.name)
            current = best.sse
    return Selection(rounds, picks, chosen, delay)


def prune(search: Search, selection: Selection, share: float) -> Selection:
    """Keep the entries that explain at least ``share`` of what the generic sparse fit captures
    of the same disagreement (the delay stays); the delay is dropped with it."""
    cache: dict[tuple, np.ndarray] = {}
    kept = []
    for pk in selection.picks:
        if pk.name == DELAY.name:
            kept.append(pk)
            continue
        pk.generic_share = _explains(search, selection.chosen, pk.name, selection.delay, cache)
        if pk.generic_share >= share:
            kept.append(pk)
    chosen = [pk.name for pk in kept if pk.name != DELAY.name]
    delay = selection.delay if any(pk.name == DELAY.name for pk in kept) else 0.0
    return Selection(selection.rounds, kept, chosen, delay, selection.dropped)


def check_reference(search: Search, selection: Selection, pairs: Pairs, *, alpha: float, floor: float) -> Selection:
    """Drop a chosen entry that is not what it says. Every entry's fit must repeat with the
    reference, its instrumental estimate agreeing with least squares
    (:func:`nanosysid.discover.sources.reference_check`): else it is fitted to the controller's
    answer to a disturbance of time (in closed loop a disturbance torque moves the angular
    acceleration an inertia correction is made of, and the rotor speeds a lag is made of). An
    entry of the rotor speeds' history must repeat nearly whole (the slope's interval reaching
    :data:`~nanosysid.discover.sources.HISTORY_REPEAT`, ``history["whole"]``), and also, added to every entry of the state in the
    library fitted at once (and the other chosen ones), still improve the held-out fit by the
    selection's own test (one-sided signed-rank over blocks at ``alpha``, a size of at least
    ``floor``): else it stands in for a function of the state (a rotor's inertia answers the
    rotor speeds' rates as a short lag does). Its coefficients as the model holds them (every
    entry chosen and the delay beside it, k_F and k_M as given) must stay within the entry's
    bound and have the shape physics gives it (:meth:`~nanosysid.effects.Effect.implausible`:
    the selection judged the folds' mean, which a share beyond 1 in the final fit need not
    follow; a slow actuation's step response never falls back by a good part of its rise,
    where the controller's answer to a disturbance, fitted beside a delay, takes a
    band-pass's). Each pick's checks are kept on it."""
    kept, dropped = [], list(selection.dropped)
    state = [n for n in COLUMN_ENTRIES[1:] if not entry(n).needs]
    g = search.grams(selection.delay)
    fitted = split_coefficients([NOMINAL.name, *selection.chosen], g.solve(search.cols(selection.chosen)))
    data = search.data(selection.delay)
    # every entry against its partial residual (what all the chosen leave, plus its own part): an
    # entry's own residual without it would hand its part to a collinear rival (a rotor spread
    # and a centre-of-gravity offset both make a steady roll torque)
    left, _ = search.residual(selection.chosen, selection.delay)
    model = None
    for pk in selection.picks:
        if pk.name == DELAY.name:
            kept.append(pk)
            continue
        others = [n for n in selection.chosen if n != pk.name]
        X = np.concatenate([fd.features[pk.name] for fd in data])
        contribution = (X @ np.array(fitted[pk.name])) * search.weights
        pk.history = reference_check(contribution, left + contribution, pairs, search.blocks, g.fold)
        holds = pk.history["holds"]
        if "history" in entry(pk.name).needs and pk.history["checked"]:
            pk.history["whole"] = bool(pk.history["ci"][1] >= HISTORY_REPEAT)
            holds = pk.history["holds"] = holds and pk.history["whole"]
        if "history" in entry(pk.name).needs:
            base = others + [n for n in state if n not in others]
            without, _ = g.heldout(search.cols(base))
            with_it, _ = g.heldout(search.cols(base + [pk.name]))
            gains = without - with_it
            z, p = pvalue(gains)
            # the gain per block the signed-rank test measures: the sum's would let one block
            # that the many state entries fitted at once extrapolate wildly decide it
            size = float(np.sqrt(max(hodges_lehmann(gains), 0.0)))
            pk.history["beyond_state"] = {"z": z, "p": p, "size": size, "holds": bool(p <= alpha and size >= floor)}
            holds = holds and pk.history["beyond_state"]["holds"]
        # as the model holds it: beside every entry chosen and the delay, k_F and k_M as given
        if model is None:
            model = split_coefficients([NOMINAL.name, *selection.chosen],
                                       search.fit_grams(selection.delay).solve(search.cols(selection.chosen)))
        pk.history["implausible"] = LIBRARY[pk.name].implausible(model[pk.name], search.vehicle)
        holds = holds and not pk.history["implausible"]
        (kept if holds else dropped).append(pk)
    chosen = [pk.name for pk in kept if pk.name != DELAY.name]
    return Selection(selection.rounds, kept, chosen, selection.delay, dropped)


def _signs_ok(name: str, thetas: np.ndarray, search: Search, chosen: list[str]) -> bool:
    """The folds' mean coefficients obey the entry's rules (:meth:`~nanosysid.effects.Effect.implausible`,
    a sign's interval two standard errors). The coefficients' joint shape is judged once the
    selection is done (:func:`check_reference`): before the delay is chosen, a lag's shares fit
    part of it and need not have a lag's shape."""
    c = LIBRARY[name]
    if c is DELAY:
        return True
    k = len(search.cols(chosen))  # the candidate's columns come last
    th = thetas[:, k:]
    return not c.implausible(th.mean(axis=0), search.vehicle, 2 * jackknife(th), shape=False)


def _best_delay(search: Search, chosen: list[str], delays: Sequence[float]) -> float:
    """The grid's delay of least residual, moved to the vertex of the parabola through it and its
    two neighbours where that leaves less still: a delay between two grid points, read off the
    nearer one, leaves a lag of a few ms that a slow actuation would fit."""
    cols = search.cols(chosen)

    def sse(d: float) -> float:
        return float(search.grams(d).sse(cols, search.grams(d).solve(cols)).sum())

    grid = sorted(set(float(d) for d in delays))
    s = [sse(d) for d in grid]
    i = int(np.argmin(s))
    if not 0 < i < len(grid) - 1:
        return grid[i]
    (d0, d1, d2), (s0, s1, s2) = grid[i - 1:i + 2], s[i - 1:i + 2]
    # the vertex of the parabola through three points (unequal spacing allowed); rounded to
    # 0.1 ms so that the normal equations built for it are found again
    den = (d1 - d0) * (s1 - s2) - (d1 - d2) * (s1 - s0)
    if den == 0:
        return d1
    vertex = d1 - 0.5 * ((d1 - d0) ** 2 * (s1 - s2) - (d1 - d2) ** 2 * (s1 - s0)) / den
    vertex = round(float(np.clip(vertex, d0, d2)), 4)
    return vertex if vertex != d1 and sse(vertex) < s1 else d1


def _explains(search: Search, chosen: list[str], name: str, delay: float, cache: dict) -> float:
    """Held-out gain of ``name`` added last, over the generic fit's on the residual without it,
    on the channels it acts on."""
    others = [n for n in chosen if n != name]
    g = search.grams(delay)
    base, _ = g.heldout(search.cols(others), per_channel=True)
    mine, _ = g.heldout(search.cols(others + [name]), per_channel=True)
    own = g.solve(search.cols(others + [name]))[-entry(name).n_columns:]
    channels = [CHANNELS.index(c) for c in channels_of(search, name, own, delay)]
    if not channels:
        return 0.0
    gain = float((base - mine)[:, channels].sum())
    key = (tuple(others), delay)
    if key not in cache:
        resid, _ = search.residual(others, delay)
        _, terms = search.terms(delay)
        cache[key] = generic.heldout_gain(terms, resid, search.blocks, g.fold)
    ggen = float(np.clip(cache[key][:, channels].sum(), 0, None))
    return 1.0 if ggen <= 0 else gain / ggen
