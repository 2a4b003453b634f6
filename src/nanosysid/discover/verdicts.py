"""Discovery's verdicts and intervals: the chosen entries' coefficients fitted on every block in
the true body's units, each pick's finding (named, or ambiguous among its alternatives) with its
95 % intervals and stability, the generic sparse fit of what remains (unnamed findings), and
what no function of the state explains."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from nanosysid.discover import generic
from nanosysid.discover.records import STATELESS, UNDETERMINED, Finding
from nanosysid.discover.sources import REPEATS, SOURCES, Pairs, source
from nanosysid.discover.search import Search, channels_of, true_torque_grams
from nanosysid.discover.select import Selection
from nanosysid.discover.stats import half_width, jackknife, pvalue
from nanosysid.discover.fit import COLUMN_ENTRIES, noise_spectrum
from nanosysid.effects import CHANNELS, DELAY, LIBRARY, NOMINAL, entry, split_coefficients
from nanosysid.vehicle import Vehicle

INERTIA = "inertia"  # the library entry that corrects the body's inertia

__all__ = ["Coefficients", "coefficients", "named", "undetermined", "Remainder", "unnamed", "stateless"]


@dataclass
class Coefficients:
    """The chosen entries fitted on every block.

    Attributes:
        names: The nominal correction (k_F, k_M) and the chosen entries, in column order.
        coef: Entry -> its coefficients, in the true body's units.
        per_fold: The same, fitted without each fold.
        measured: The coefficients of every column in the measured torque's units (the
            disagreement analysis reads the residual these leave).
        rivals: The same fit with each plausible rival added: entry -> coefficients, one per rival.
        rivals_per_fold: Each rival fit's coefficients fitted without each fold.
    """

    names: list[str]
    coef: dict[str, list[float]]
    per_fold: list[dict[str, list[float]]]
    measured: np.ndarray
    rivals: list[dict[str, list[float]]]
    rivals_per_fold: list[list[dict[str, list[float]]]]


def coefficients(search: Search, selection: Selection, vehicle: Vehicle,
                 inertia_z_range: tuple[float, float] | None = None) -> Coefficients:
    """The final fit of the chosen entries, the fits without each fold, and the fits with each
    plausible rival: the eligible candidates the selection passed over, and the physically
    plausible candidates of its last round, which it found too small or not significant (a
    collinear entry adds little once the chosen ones have taken its share, which is why its
    absence is no evidence). A coefficient that moves when a rival joins is uncertain by that
    much beyond the folds' scatter (collinear or misspecified columns bias it; the folds cannot
    show a bias); each rival fit's own scatter over the folds is kept too (a rival that takes
    over a collinear share leaves the coefficient less determined than the chosen fit does).
    Where the inertia correction is chosen and ``inertia_z_range`` (kg m²) is given, the fits
    with the yaw inertia held at each end of it are rivals too: the flights tell the yaw
    torques' ratios to J_z, so k_M's refit and a rotor inertia move with it."""
    chosen, delay = selection.chosen, selection.delay
    g = search.fit_grams(delay)
    cols = search.cols(chosen)
    measured = g.solve(cols)
    g = true_torque_grams(search, g, chosen, cols, vehicle)
    theta = g.solve(cols)
    _, thetas = g.heldout(cols)
    names = [NOMINAL.name, *chosen]
    passed_over = {n for pk in selection.picks for n in pk.competitors + [pk.name]}
    last = {c.name for c in selection.rounds[-1] if c.plausible} if selection.rounds else set()
    rivals = sorted((passed_over | last) - set(chosen) - {DELAY.name})
    rival_coef, rival_folds = [], []
    for n in rivals:
        alt_cols = search.cols(chosen + [n])
        alt_g = true_torque_grams(search, search.fit_grams(delay), chosen + [n], alt_cols, vehicle)
        rival_coef.append(split_coefficients(names + [n], alt_g.solve(alt_cols)))
        rival_folds.append([split_coefficients(names + [n], t) for t in alt_g.heldout(alt_cols)[1]])
    if INERTIA in chosen and inertia_z_range is not None:
        for jz in inertia_z_range:
            alt_g = true_torque_grams(search, search.fit_grams(delay), chosen, cols, vehicle, yaw_inertia=float(jz))
            rival_coef.append(split_coefficients(names, alt_g.solve(cols)))
            rival_folds.append([split_coefficients(names, t) for t in alt_g.heldout(cols)[1]])
    return Coefficients(names, split_coefficients(names, theta), [split_coefficients(names, t) for t in thetas],
                        measured, rival_coef, rival_folds)


def named(search: Search, selection: Selection, fit: Coefficients, vehicle: Vehicle,
          delays: Sequence[float], inertia_z_range: tuple[float, float] | None = None) -> list[Finding]:
    """One finding per pick: named, or ambiguous where an alternative is not named later; with
    each coefficient's 95 % interval (the union of the chosen fit's and every rival fit's
    interval, each its value widened by its folds' jackknife interval) and the pick's stability.

    ``inertia_z_range`` (kg m², the yaw inertia's plausible range) widens the yaw inertia
    correction's interval to reach every value in it: the yaw torque is read through the yaw
    inertia, with which k_M was identified too, so the flights tell the yaw coefficients' ratios
    to J_z rather than J_z (:func:`nanosysid.identify.with_inertia_range` does the same for k_M).
    A delay chosen at the search's largest has no upper bound: the truth may lie beyond it."""
    chosen, delay = selection.chosen, selection.delay
    findings: list[Finding] = []
    named_later = set(chosen) | ({DELAY.name} if delay else set())
    for pk in selection.picks:
        name = pk.name
        c = LIBRARY[name]
        if c is DELAY:
            params = {DELAY.params[0]: delay}
            stderr = {DELAY.params[0]: _delay_stderr(search, chosen, (0.0,) + tuple(delays))}
            channels = CHANNELS
        else:
            th = np.array(fit.coef[name])
            params = dict(zip(c.params, c.values(th, vehicle)))
            # jackknife of the physical values themselves: the map from the columns' coefficients
            # may be nonlinear (inertia) or mix them (rotor spread)
            se = jackknife(np.array([c.values(fc[name], vehicle) for fc in fit.per_fold]))
            stderr = dict(zip(c.params, (float(x) for x in se)))
            channels = channels_of(search, name, th, delay)
            spread = np.array([list(params.values())] + [c.values(rc[name], vehicle) for rc in fit.rivals])
        alts = [a for a in pk.alternatives if a not in named_later]
        ev = pk.evidence()
        ev["stderr"] = stderr
        half = {k: half_width(stderr[k], search.folds) for k in params}
        if c is DELAY:
            # the search reads the delay off a grid: the truth may lie anywhere within half a grid
            # step of the point chosen, which the folds' spread alone (zero when every fold picks
            # the same point) does not say
            below, above = _grid_gaps((0.0,) + tuple(delays), delay)
            if delay >= max(delays):
                above = math.inf
            ev["ci"] = {k: (params[k] - half[k] - below, params[k] + half[k] + above) for k in params}
        else:
            ev["rival_range"] = {k: (float(spread[:, i].min()), float(spread[:, i].max())) for i, k in enumerate(params)}
            own = [half[k] for k in params]
            halves = np.array([own] + [_rival_half(c, name, folds, vehicle, search.folds, own)
                                       for folds in fit.rivals_per_fold])
            lo, hi = (spread - halves).min(axis=0), (spread + halves).max(axis=0)
            if c.bound is not None:  # beyond its bound no fit of the entry is plausible (the selection's rule)
                reach = c.bound * np.abs(np.asarray(c.nominal(vehicle)))
                lo, hi = np.maximum(lo, np.minimum(-reach, spread[0])), np.minimum(hi, np.maximum(reach, spread[0]))
            ev["ci"] = {k: (float(lo[i]), float(hi[i])) for i, k in enumerate(params)}
            if name == INERTIA and inertia_z_range is not None:
                k, jz = c.params[2], vehicle.inertia[2]
                lo, hi = ev["ci"][k]
                ev["ci"][k] = (min(lo, inertia_z_range[0] - jz), max(hi, inertia_z_range[1] - jz))
                ev["inertia_z_range"] = [float(x) for x in inertia_z_range]
        ev["stability"] = _stability(search, chosen, name, pk.competitors, delay)
        if pk.generic_share is not None:
            ev["generic_share"] = pk.generic_share
        if alts:
            ev["used"] = name
            ev["separate_by"] = {a: LIBRARY[a].excited_by for a in [name, *alts]}
            findings.append(Finding("ambiguous", None, channels, params, ev, (name, *alts)))
        else:
            findings.append(Finding("named", name, channels, params, ev))
    return findings


def undetermined(findings: Sequence[Finding]) -> None:
    """A named finding whose every coefficient's 95 % interval (``evidence["ci"]``, the final
    one) holds zero becomes ``undetermined`` (``evidence["was"]``: named): nothing excludes that
    the effect is absent. The augmented model still uses it. The delay, whose interval starts at
    the grid's first point, is left as it is."""
    for f in findings:
        ci = f.evidence.get("ci") or {}
        if f.verdict == "named" and f.name != DELAY.name and ci and all(lo <= 0.0 <= hi for lo, hi in ci.values()):
            f.evidence["was"] = f.verdict
            f.verdict = UNDETERMINED


def _rival_half(c, name: str, folds: Sequence[dict[str, list[float]]], vehicle: Vehicle, n_folds: int,
                own: Sequence[float]) -> np.ndarray:
    """Half-widths of a rival fit's own 95 % intervals of entry ``c``'s values (its folds'
    jackknife); where a fold puts a value beyond the entry's physical bound, or not finite, the
    rival does not determine it, and the chosen fit's half-widths ``own`` are used."""
    vals = np.array([c.values(fc[name], vehicle) for fc in folds])
    ok = np.all(np.isfinite(vals))
    if ok and c.bound is not None:
        ok = bool(np.all(np.abs(vals) <= c.bound * np.abs(np.asarray(c.nominal(vehicle)))))
    if not ok:
        return np.asarray(own, dtype=float)
    return np.array([half_width(x, n_folds) for x in jackknife(vals)])


@dataclass
class Remainder:
    """What the chosen entries leave, and the generic fit of it.

    Attributes:
        findings: The unnamed findings, one per channel the generic fit captures significantly.
        terms: Their sparse terms: name -> coefficient (physical units), for the augmented model.
        fits: Per such channel, its index and the terms' coefficients ``(M,)`` (physical units).
        left: The weighted residual ``(N, 6)`` that neither the entries nor the terms explain.
    """

    findings: list[Finding]
    terms: dict[str, float]
    fits: list[tuple[int, np.ndarray]]
    left: np.ndarray


def unnamed(search: Search, selection: Selection, *, alpha: float, floor: float, total: float) -> Remainder:
    """Channel by channel, the generic sparse fit of the residual the chosen entries leave: an
    unnamed finding where it captures significantly more than nothing (Bonferroni over the six
    channels) by at least ``floor`` noise floors."""
    resid, _ = search.residual(selection.chosen, selection.delay, model=True)
    lib, terms = search.terms(selection.delay)
    gains = generic.heldout_gain(terms, resid, search.blocks, search.grams(selection.delay).fold)
    n_samples = len(search.blocks)
    out = Remainder([], {}, [], resid)
    state_fit: dict[int, np.ndarray] = {}
    for c in range(6):
        z, p = pvalue(gains[:, c])
        p = min(1.0, 6 * p)
        size = float(np.sqrt(max(gains[:, c].sum(), 0.0) / n_samples))
        if p > alpha or size < floor:
            continue
        coef_c = generic.sparse_fit(terms, resid[:, [c]])
        raw, shown = generic.terms_of(coef_c, lib, [c], search.weights)
        if not raw:
            continue
        state_fit[c] = terms @ coef_c[0]
        out.terms.update(raw)
        out.fits.append((c, coef_c[0] / search.weights[c]))
        out.findings.append(Finding("unnamed", None, (CHANNELS[c],), shown, {
            "heldout_gain": float(gains[:, c].sum() / total), "size": size, "z": z, "p": p,
            "blocks_improved": int((gains[:, c] > 0).sum()), "blocks": int(len(gains))}))
    # what neither an entry nor the generic terms of the state explain, channel by channel
    out.left = resid - np.column_stack([state_fit.get(c, np.zeros(len(resid))) for c in range(6)])
    return out


# The least size (noise floors) of a residual called "not a function of the state": the excess is
# measured against the noise floor's estimate, and a correlated error the estimate misses (the
# rotor speeds' interpolation, their rates' smoothing) leaves a few tenths of it in every block
# of a world with no disturbance at all; a disturbance is only said where it is at least as large
# as the noise itself
STATELESS_FLOOR = 1.0


def _saturated(search: Search, delay: float) -> np.ndarray:
    """The weighted residual ``(N, 6)`` left by every library entry of the state fitted at once,
    k_F and k_M held as the model holds them (a refit on closed-loop flights scales the rotors'
    torque down by the disturbance the controller answers with it)."""
    names = [n for n in COLUMN_ENTRIES[1:] if not entry(n).needs]
    return search.residual(names, delay, model=True)[0]


TIME = SOURCES[1]


def stateless(left: np.ndarray, search: Search, alpha: float, floor: float, total: float,
              pairs: Pairs | None = None, delay: float = 0.0) -> list[Finding]:
    """The channels whose residual ``left`` (weighted: noise floors) stays above the noise after
    the entries and the generic terms of the state: the one-sided Wilcoxon test that the blocks'
    mean squares exceed 1 (the noise's), Bonferroni over the six channels, and a size of at least
    ``floor`` (the root of the excess mean square). Given runs of one reference (``pairs``),
    what it is a function of (:func:`nanosysid.discover.sources.source`): one that does not
    repeat with the reference is of time; one that repeats is unnamed. Without that answer, it
    must also stay above the noise after every state entry of the library fitted at once, the
    generic terms and the rotor speeds one by one (:func:`nanosysid.discover.fit.rotor_products`)
    on what they leave (else it is an unnamed function of the state, none of whose parts was
    significant alone). Each is a finding "not a function of the state", with the frequency
    band holding the middle half of its power."""
    B = int(search.blocks.max()) + 1
    counts = np.bincount(search.blocks, minlength=B)
    dt = float(np.median(np.diff(search.flights[0].t)))
    out = []
    saturated = None

    def above(x, c):
        # each block against its own noise (a block of sharp corners is several times noisier
        # than one of a slow sweep): its mean square over the one its noise alone would give
        ms = np.bincount(search.blocks, weights=x ** 2, minlength=B) / np.maximum(counts, 1)
        excess = (ms / search.block_noise[:, c] - 1.0) * counts
        z, p = pvalue(excess)
        return excess, z, min(1.0, 6 * p), float(np.sqrt(max(excess.sum(), 0.0) / counts.sum()))

    least = max(floor, STATELESS_FLOOR)
    for c in range(6):
        excess, z, p, size = above(left[:, c], c)
        if p > alpha or size < least:
            continue
        # what the residual is a function of, given runs of one reference: a function of the
        # state repeats with the reference, a disturbance is a new realisation every flight
        found = source(left[:, c], pairs, search.blocks, alpha, search.flight_index) if pairs is not None else None
        # a residual that does not repeat is of time, whatever fits it: the controller answers a
        # disturbance through the rotor speeds, so a fit of the rotor terms on every sample
        # absorbs one it fights. Otherwise, before "not a function of the state": every state
        # entry of the library at once (an inertia, a torque scale, the drags and rotor terms
        # together can leave what none alone was significant for), with the generic terms on
        # what they leave
        if found is None or found.get("source") != TIME:
            if saturated is None:
                saturated = _saturated(search, delay)
                rotors = search.rotor_products(delay)
                rotors = rotors / np.maximum(np.abs(rotors).max(axis=0), 1e-300)
            sat = saturated[:, c] - search.terms(delay)[1] @ generic.sparse_fit(search.terms(delay)[1],
                                                                                saturated[:, [c]])[0]
            # and the rotor speeds one by one (their differences and products with the velocity
            # and rates: each rotor's own drag and thrust share), fitted on every sample: 21
            # columns take a few thousandths of the noise's power from thousands of samples
            sat = sat - rotors @ np.linalg.lstsq(rotors, sat, rcond=1e-10)[0]
            _, zs, ps, ss = above(sat, c)
            # what the state fit leaves need only be a finding's size: the disturbance was
            # already found as large as the noise before it
            if ps > alpha or ss < floor:
                out.append(Finding("unnamed", None, (CHANNELS[c],), {}, {
                    "heldout_gain": float(max(excess.sum(), 0.0) / total), "size": size, "z": z, "p": p,
                    "blocks_improved": int((excess > 0).sum()), "blocks": B, "saturated": True,
                    "saturated_p": ps, "saturated_size": ss, "added": False}))
                continue
        evidence = {"heldout_gain": float(max(excess.sum(), 0.0) / total), "size": size, "z": z, "p": p,
                    "blocks_improved": int((excess > 0).sum()), "blocks": B,
                    "band": _band(left[:, c], search.blocks, dt,
                                  (search.noise_parts[:, c] / search.noise[c]) ** 2, search.window, search.order),
                    "rms": float(np.sqrt(max((excess * search.block_noise[:, c]).sum(), 0.0) / counts.sum())
                                 / search.weights[c])}
        if found is not None:
            evidence["source"] = found
        # a residual that repeats with the reference is a function of what the reference makes of
        # the flight: the state beyond the library's entries and terms, or the input history beyond
        # its lags; no test here tells the two apart, so it is unnamed, never "not of the state"
        repeats = evidence.get("source", {}).get("source") == REPEATS
        out.append(Finding("unnamed" if repeats else STATELESS, None, (CHANNELS[c],), {},
                           {**evidence, "repeats": True, "added": False} if repeats else evidence))
    return out


def _band(x: np.ndarray, blocks: np.ndarray, dt: float, parts: np.ndarray, window: int, order: int) -> str:
    """The frequency band (Hz) between the quartiles of the power of ``x`` (weighted: noise
    floors) above the noise's, from the spectra of its blocks; ``parts``: the noise's variance
    shares through the smoothing and through the derivative
    (:func:`~nanosysid.discover.fit.noise_spectrum`). Where the noise leaves nothing, the band of
    all the power."""
    n = 256
    total = noise = 0.0
    for b in np.unique(blocks):
        seg = x[blocks == b]
        seg = seg - seg.mean()
        w = np.hanning(len(seg))
        total = total + np.abs(np.fft.rfft(seg * w, n=n)) ** 2
        noise = noise + (w ** 2).sum()
    freqs = np.fft.rfftfreq(n, dt)
    above = np.maximum(total - noise * noise_spectrum(parts, window, order, dt, n), 0.0)
    psd = above if above.sum() > 0 else total
    cum = np.cumsum(psd) / max(np.sum(psd), 1e-300)
    lo, hi = freqs[np.searchsorted(cum, 0.25)], freqs[min(np.searchsorted(cum, 0.75), len(freqs) - 1)]
    return f"{lo:.2g}-{hi:.2g} Hz"


def _grid_gaps(grid: Sequence[float], value: float) -> tuple[float, float]:
    """Half the distance from ``value``, a point of ``grid``, to its neighbours below and above
    (0 at the grid's ends: the search tries nothing beyond them)."""
    g = np.unique(np.asarray(grid, dtype=float))
    i = int(np.argmin(np.abs(g - value)))
    return (float(g[i] - g[i - 1]) / 2 if i > 0 else 0.0, float(g[i + 1] - g[i]) / 2 if i + 1 < len(g) else 0.0)


def _delay_stderr(search: Search, chosen: list[str], delays: Sequence[float]) -> float:
    """Jackknife of the delay over the folds: chosen on all folds but one, in turn."""
    cols = search.cols(chosen)
    picks = []
    for k in range(search.folds):
        train = np.flatnonzero(search.grams(0.0).fold != k)
        sse = {d: search.grams(d).sse(cols, search.grams(d).solve(cols, train), train).sum() for d in delays}
        picks.append(min(sse, key=sse.get))
    return float(jackknife(np.array(picks)[:, None])[0])


def _stability(search: Search, chosen: list[str], name: str, competitors: list[str], delay: float) -> float:
    """Share of the held-out folds on which ``name``, with the other chosen entries, leaves less
    residual than each competitor in its place: the selection's own criterion, fold by fold (an
    in-sample comparison would favour the competitor with more columns)."""
    rivals = [c for c in competitors if c not in (DELAY.name, name) and c not in chosen]
    if not rivals or name == DELAY.name:
        return 1.0
    g = search.grams(delay)
    others = [n for n in chosen if n != name]

    def per_fold(n: str) -> np.ndarray:
        blocks, _ = g.heldout(search.cols(others + [n]))
        return np.bincount(g.fold, weights=blocks, minlength=search.folds)

    mine = per_fold(name)
    return float(np.mean(np.all([mine <= per_fold(c) for c in rivals], axis=0)))
