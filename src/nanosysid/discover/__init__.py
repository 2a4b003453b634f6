"""Model-discrepancy discovery: where the nominal physics and the measurements disagree, and
for every disagreement that stands above the noise a verdict: which named physical effect
explains it, that the data cannot tell two named effects apart, or that no named effect does
(and then a sparse fit of generic terms that captures it).

Example::

    from nanosysid import discover
    res = discover.run(train_flights, test_flights)
    for f in res.findings:              # most important first
        f.verdict, f.name, f.alternatives, f.channels, f.params, f.evidence["ci"]
    res.found                           # the "named" findings
    res.before.simerr, res.after.simerr # nominal and augmented model on test_flights
    res.model                           # the augmented predictor

**The nominal model** is ``physics_full`` (rigid body with the torque equation) with k_F and k_M as
the identify stage found them on the training flights (identified here when no vehicle is
given); k_F and k_M are refitted alongside every candidate. **The candidates** are the library of
:mod:`nanosysid.effects` (knowledge from the literature, several forms of one effect where the
literature has several, and corrections of the nominal mass, inertia and arm); this package
never imports the simulator's world.

**The rule.** Residuals are weighted by their noise floor (:func:`~nanosysid.discover.fit.noise_floor`,
estimated from the measurements), cut into blocks of ``block`` seconds and dealt to ``folds`` folds;
every score is held out (:mod:`nanosysid.discover.fit`). Forward selection: each round, every
candidate not yet chosen is added to the chosen ones, and its held-out gain is measured block by
block. Under the null hypothesis that it explains nothing, a block's gain is as likely negative as
positive: the one-sided Wilcoxon signed-rank test over the blocks (a sign-flip test on ranks, so a
few violent blocks neither make nor break it) gives a p-value, multiplied by the number of
candidates tried in the round (Bonferroni). A candidate is *eligible* when that p-value is below
``alpha``, its size (the root of its held-out gain per sample, in noise floors) is at least
``floor`` (smaller than a quarter of the noise, an effect moves no benchmark figure), and no
coefficient with a physical sign (a drag coefficient, a rotor inertia) comes out negative by more
than two standard errors. The eligible candidate with the largest gain is
chosen. Candidates it is not significantly better than (the same paired sign-flip test on the
difference of their held-out errors, at ``alpha``) are its *alternatives*: if none of them is chosen
later, the finding is **ambiguous**, otherwise **named**. The delay of the recorded rotor speeds
is a search over a grid, nested inside the folds: each fold chooses its delay on the other folds.

A chosen entry is kept only if it explains at least ``share`` of what a generic sparse fit
(:mod:`nanosysid.discover.generic`) captures of the same disagreement (its held-out gain without
it, on its own channels): an entry that only correlates with an effect outside the library is
not named. What remains after the chosen entries is tested channel by channel with the generic
fit (the same sign-flip test, Bonferroni over the six channels): a channel where it captures
significantly more than nothing is an **unnamed** finding, and its sparse terms join the
augmented model. Anything that does not pass these tests is below the noise floor and is not a
finding.

**The numbers of a finding.** Its coefficients are fitted on every block, in the true body's
units: where the inertia correction is chosen, every other torque column is scaled by
``J / (J + dJ)`` and refitted until ``dJ`` settles, so k_M, a rotor inertia or a damping is the
one the augmented model (which integrates with ``J + dJ``) must apply. Their 95 % intervals
take both kinds of uncertainty: the folds' scatter (a delete-a-fold jackknife of the physical
values, Student's t for the folds' number) around the range the value takes when each plausible
rival (an eligible candidate the selection passed over) joins the fit, which the folds cannot
show: a collinear or misspecified column biases a coefficient the same way in every fold. Its
stability is the share of the folds on which it beats, held out, every other eligible candidate
of its round.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.stats import norm, t as student_t, wilcoxon

from nanosysid import benchmark
from nanosysid.dataio import Flight
from nanosysid.discover import generic
from nanosysid.discover.analysis import disagreement
from nanosysid.discover.fit import COLUMN_ENTRIES, FlightData, Grams, block_ids, flight_data, measured_wrench, noise_floor
from nanosysid.discover.model import AugmentedPredictor, AugmentedStep
from nanosysid.effects import CHANNELS, DELAY, LIBRARY, NOMINAL, entry, refitted_vehicle, split_coefficients
from nanosysid.errors import ConfigError, DataError, PredictionError
from nanosysid.identify import identify
from nanosysid.metrics import QUANTITIES
from nanosysid.vehicle import Vehicle

__all__ = ["run", "Finding", "DiscoveryResult", "LIBRARY", "CHANNELS", "VERDICTS", "STATELESS"]

VERDICTS = ("named", "ambiguous", "unnamed", "not a function of the state")
STATELESS = VERDICTS[3]


@dataclass
class Finding:
    """One disagreement above the noise floor and its verdict.

    Attributes:
        verdict: ``"named"``, ``"ambiguous"`` or ``"unnamed"``.
        name: The library entry named (verdict ``"named"``), else None.
        alternatives: Verdict ``"ambiguous"``: the entries that explain it equally well, the one
            the augmented model uses first.
        channels: The body-wrench channels it acts on (of :data:`CHANNELS`).
        params: Coefficient name (with unit) -> fitted value: of the entry (named), of the entry
            the augmented model uses (ambiguous), of the generic terms kept (unnamed).
        evidence: ``heldout_gain`` (share of the nominal residual's weighted sum of squares,
            held out), ``z``, ``p`` (Bonferroni-adjusted), ``blocks_improved`` / ``blocks``,
            ``stderr`` (jackknife over the folds) and ``ci`` per coefficient (95 %: the range
            its value takes when each plausible rival joins the fit, widened by the folds'
            interval, Student's t with one degree of freedom fewer than folds), ``rival_range``,
            ``stability`` (share of the held-out folds on which it beats every other eligible
            candidate of its round), ``round``; ambiguous: ``used``, ``separate_by``; unnamed: ``regime``,
            ``band``, and ``added`` False where its terms would make the training rollouts
            diverge (they are then left out of the augmented model).
    """

    verdict: str
    name: str | None
    channels: tuple[str, ...]
    params: dict[str, float]
    evidence: dict[str, Any]
    alternatives: tuple[str, ...] = ()

    @property
    def entry(self) -> str | None:
        """The library entry the augmented model uses for it (None: generic terms)."""
        return self.name or (self.alternatives[0] if self.alternatives else None)

    @property
    def touches(self) -> tuple[str, ...]:
        if self.entry is not None:
            return LIBRARY[self.entry].touches
        return tuple(dict.fromkeys(q for c in self.channels for q in (("p", "v") if c.startswith("F") else ("R", "w"))))


@dataclass
class DiscoveryResult:
    """What :func:`run` found, and the benchmark scores on the test flights."""

    findings: list[Finding]
    before: benchmark.Scores
    after: benchmark.Scores
    model: AugmentedPredictor
    nominal: AugmentedPredictor
    vehicle: Vehicle
    rounds: list[list[dict[str, Any]]]
    alpha: float
    floor: float
    noise: np.ndarray
    oracle: benchmark.Scores | None = None
    sindy: dict[str, Any] | None = None
    analysis: dict[str, Any] = field(default_factory=dict)
    limit: benchmark.Scores | None = None

    @property
    def found(self) -> list[Finding]:
        """The findings with verdict ``"named"``."""
        return [f for f in self.findings if f.verdict == "named"]

    @property
    def name(self) -> str:
        parts = [f.entry for f in self.findings if f.entry] + (["terms"] if self.unnamed else [])
        return "+".join(["physics"] + parts)

    @property
    def unnamed(self) -> list[Finding]:
        return [f for f in self.findings if f.verdict == "unnamed"]


def _pvalue(g: np.ndarray) -> tuple[float, float]:
    """One-sided Wilcoxon signed-rank test that the per-block gains ``g`` lean positive: the
    equivalent normal ``z`` and p."""
    g = g[g != 0]
    if len(g) < 2:
        return 0.0, 1.0
    p = float(wilcoxon(g, alternative="greater").pvalue)
    return float(norm.isf(p)), p


def _jackknife(thetas: np.ndarray) -> np.ndarray:
    """Delete-a-group jackknife standard error from the estimates ``(n, k)`` each fitted without
    one of ``n`` groups."""
    n = len(thetas)
    return np.sqrt((n - 1) / n * ((thetas - thetas.mean(axis=0)) ** 2).sum(axis=0))


def _half_width(stderr: float, groups: int, level: float = 0.95) -> float:
    """Half-width of the ``level`` interval from a jackknife over ``groups`` groups: the standard
    error has ``groups - 1`` degrees of freedom, so the quantile is Student's t (with 10 folds,
    2.26 standard errors rather than the normal 1.96, which would cover 92 %)."""
    return float(student_t.ppf(0.5 + level / 2, max(groups - 1, 1)) * stderr)


class _Search:
    """Regression data and block normal equations per delay, built once and shared by every round."""

    def __init__(self, flights: Sequence[Flight], vehicle: Vehicle, window: int, order: int, block: float,
                 folds: int) -> None:
        self.flights, self.vehicle, self.window, self.order = list(flights), vehicle, window, order
        self.measured = [measured_wrench(f, vehicle, window, order) for f in self.flights]
        self.noise = noise_floor(self.flights, vehicle, window, order)
        self.weights = 1.0 / np.maximum(self.noise, 1e-12)
        self._data: dict[float, list[FlightData]] = {}
        self._grams: dict[float, Grams] = {}
        self._terms: dict[float, tuple[generic.TermLibrary, np.ndarray]] = {}
        dt = float(np.median(np.diff(self.flights[0].t)))
        self.blocks = block_ids(self.data(0.0), max(1, int(round(block / dt))))
        n_blocks = int(self.blocks.max()) + 1
        if n_blocks < 4:
            raise DataError(f"discover: the training flights make {n_blocks} blocks of {block:g} s; at least 4 are "
                            "needed to hold some out (give longer flights or a shorter discover.block)")
        self.folds = min(folds, n_blocks // 2)  # short data: fewer, larger folds
        self.offsets = {}
        k = 0
        for name in COLUMN_ENTRIES:
            P = entry(name).n_columns
            self.offsets[name] = np.arange(k, k + P)
            k += P

    def data(self, delay: float) -> list[FlightData]:
        key = round(float(delay), 6)
        if key not in self._data:
            self._data[key] = [flight_data(f, self.vehicle, key, window=self.window, order=self.order, measured=m)
                               for f, m in zip(self.flights, self.measured)]
        return self._data[key]

    def grams(self, delay: float) -> Grams:
        key = round(float(delay), 6)
        if key not in self._grams:
            d = self.data(key)
            X = np.concatenate([np.concatenate([fd.features[n] for n in COLUMN_ENTRIES], axis=-1) for fd in d])
            y = np.concatenate([fd.r for fd in d])
            self._grams[key] = Grams(X, y, self.weights, self.blocks, self.folds)
        return self._grams[key]

    def terms(self, delay: float) -> tuple[generic.TermLibrary, np.ndarray]:
        """The generic terms' library and their values on every sample ``(N, M)``."""
        key = round(float(delay), 6)
        if key not in self._terms:
            signals = np.concatenate([fd.terms for fd in self.data(key)])
            lib = generic.TermLibrary(signals)
            self._terms[key] = (lib, lib(signals))
        return self._terms[key]

    def touched(self, name: str) -> set[int]:
        """The channels an entry's columns act on."""
        if name == DELAY.name:
            return set(range(6))
        f = self.data(0.0)[0].features[name]
        return set(np.flatnonzero(np.any(f != 0, axis=(0, 2))).tolist())

    def cols(self, names: Sequence[str]) -> np.ndarray:
        return np.concatenate([self.offsets[n] for n in [NOMINAL.name, *names]])

    def residual(self, names: Sequence[str], delay: float) -> tuple[np.ndarray, np.ndarray]:
        """Weighted residual left by ``names`` fitted on every block ``(N, 6)``, and the coefficients."""
        g = self.grams(delay)
        cols = self.cols(names)
        theta = g.solve(cols)
        d = self.data(delay)
        X = np.concatenate([np.concatenate([fd.features[n] for n in [NOMINAL.name, *names]], axis=-1) for fd in d])
        y = np.concatenate([fd.r for fd in d])
        return (y - X @ theta) * self.weights, theta

    def nested_delay(self, names: Sequence[str], delays: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """Held-out SSE per block with the delay chosen on the other folds, and each fold's delay."""
        cols = self.cols(names)
        fits = {d: self.grams(d) for d in delays}
        out, chosen = np.zeros(int(self.blocks.max()) + 1), np.zeros(self.folds)
        for k in range(self.folds):
            train = np.flatnonzero(fits[delays[0]].fold != k)
            test = np.flatnonzero(fits[delays[0]].fold == k)
            best, best_sse, best_theta = None, np.inf, None
            for d, g in fits.items():
                th = g.solve(cols, train)
                s = g.sse(cols, th, train).sum()
                if s < best_sse:
                    best, best_sse, best_theta = d, s, th
            chosen[k] = best
            out[test] = fits[best].sse(cols, best_theta, test)
        return out, chosen


def _true_torque_grams(search: _Search, g: Grams, chosen: Sequence[str], cols: np.ndarray, vehicle: Vehicle,
                       iterations: int = 8) -> Grams:
    """The normal equations in which every torque coefficient is in the true body's units.

    The measured torque is ``J dw/dt + w x Jw`` with the *nominal* J. Where the body's inertia
    is ``J + dJ``, every torque the rotors and the effects exert shows up in it shrunk by
    ``J / (J + dJ)`` per axis: a k_M refit or a rotor inertia fitted there is the true one
    times that ratio, and one rotor inertia cannot serve the roll/pitch gyroscopic torque and
    the yaw reaction at once when the ratios differ by axis. The augmented model integrates
    with ``J + dJ``, so the torque columns of every entry but the inertia correction itself are
    scaled by ``J / (J + dJ)`` and the fit is repeated with the ``dJ`` it finds (a fixed point,
    reached in a few rounds): the coefficients are then the true body's, one parametrisation
    for the fit and the model.
    """
    if "inertia" not in chosen:
        return g
    J = np.asarray(vehicle.inertia)
    own = np.concatenate([search.offsets[n] for n in [NOMINAL.name, *chosen] if n == "inertia"])
    scale = np.ones((6, g.P))
    fitted = g
    for _ in range(iterations):
        c = np.array(split_coefficients([NOMINAL.name, *chosen], fitted.solve(cols))["inertia"])
        ratio = np.clip((J - c) / J, 0.2, 5.0)  # J / (J + dJ), with dJ = c J / (J - c)
        new = np.ones((6, g.P))
        new[3:, :] = ratio[:, None]
        new[3:, own] = 1.0
        if np.allclose(new, scale, rtol=1e-6):
            break
        scale = new
        fitted = g.scaled(scale)
    return fitted


def _stateless(left: np.ndarray, search: _Search, alpha: float, floor: float, total: float) -> list[Finding]:
    """The channels whose residual ``left`` (weighted: noise floors) stays above the noise after
    the entries and the generic terms of the state: the one-sided Wilcoxon test that the blocks'
    mean squares exceed 1 (the noise's), Bonferroni over the six channels, and a size of at least
    ``floor`` (the root of the excess mean square). Each is a finding "not a function of the
    state", with the frequency band holding the middle half of its power."""
    B = int(search.blocks.max()) + 1
    counts = np.bincount(search.blocks, minlength=B)
    dt = float(np.median(np.diff(search.flights[0].t)))
    out = []
    for c in range(6):
        ms = np.bincount(search.blocks, weights=left[:, c] ** 2, minlength=B) / np.maximum(counts, 1)
        excess = (ms - 1.0) * counts
        z, p = _pvalue(excess)
        p = min(1.0, 6 * p)
        size = float(np.sqrt(max(excess.sum(), 0.0) / counts.sum()))
        if p > alpha or size < floor:
            continue
        out.append(Finding(STATELESS, None, (CHANNELS[c],), {}, {
            "heldout_gain": float(max(excess.sum(), 0.0) / total), "size": size, "z": z, "p": p,
            "blocks_improved": int((excess > 0).sum()), "blocks": B, "band": _band(left[:, c], search.blocks, dt),
            "rms": float(np.sqrt(max(excess.sum(), 0.0) / counts.sum()) / search.weights[c])}))
    return out


def _band(x: np.ndarray, blocks: np.ndarray, dt: float) -> str:
    """The frequency band (Hz) between the quartiles of the power of ``x``, from the spectra of
    its blocks."""
    psd, freqs = 0.0, None
    for b in np.unique(blocks):
        seg = x[blocks == b]
        seg = seg - seg.mean()
        spec = np.abs(np.fft.rfft(seg * np.hanning(len(seg)), n=256)) ** 2
        psd = psd + spec
        freqs = np.fft.rfftfreq(256, dt)
    cum = np.cumsum(psd) / max(np.sum(psd), 1e-300)
    lo, hi = freqs[np.searchsorted(cum, 0.25)], freqs[min(np.searchsorted(cum, 0.75), len(freqs) - 1)]
    return f"{lo:.2g}-{hi:.2g} Hz"


def _channels_of(search: _Search, name: str, theta: np.ndarray, delay: float) -> tuple[str, ...]:
    """Channels where an entry's fitted wrench carries at least a fifth of its largest (in noise units)."""
    X = np.concatenate([fd.features[name] for fd in search.data(delay)])
    w = (X @ theta) * search.weights
    rms = np.sqrt((w ** 2).mean(axis=0))
    if rms.max() <= 0:
        return ()
    return tuple(CHANNELS[c] for c in np.flatnonzero(rms >= 0.2 * rms.max()))


# training flights that move less than this (RMS distance from each flight's mean position, m,
# and RMS angular rate, rad/s) excite no effect of the library: drags need speed, gyroscopic and
# inertia terms need rates (a speed's RMS would not do: a hover's measured velocity is mostly
# the estimator's drift)
MIN_TRAVEL, MIN_RATE = 0.05, 0.1


def _check_excitation(flights: Sequence[Flight]) -> None:
    """Refuse to judge flights that barely move (a hover): every effect's regressor is near zero,
    so its absence would be read as "nothing found"."""
    travel = float(np.sqrt(np.mean(np.concatenate(
        [np.sum((f.y[:, 0:3] - f.y[:, 0:3].mean(axis=0)) ** 2, axis=1) for f in flights]))))
    rate = float(np.sqrt(np.mean(np.concatenate([np.sum(f.y[:, 10:13] ** 2, axis=1) for f in flights]))))
    if travel < MIN_TRAVEL and rate < MIN_RATE:
        raise DataError(f"discover cannot judge: the training flights barely move (RMS distance from their mean "
                        f"position {travel:.3f} m, RMS angular rate {rate:.3f} rad/s, below {MIN_TRAVEL:g} and "
                        f"{MIN_RATE:g}), so no effect of the library is excited; fly trajectories that move (square, "
                        "random, chirp)")


def run(train_flights: Sequence[Flight], test_flights: Sequence[Flight], *, vehicle: Vehicle | None = None,
        alpha: float = 0.01, floor: float = 0.25, share: float = 0.5, delays: Sequence[float] = tuple(np.arange(1, 17) * 0.005),
        window: int = 15, order: int = 3, block: float = 2.0, folds: int = 10, horizon: int = 50,
        oracle: Any = None, limit: Any = None, analysis: bool = True, sindy: bool = False,
        batch_size: int = 8192) -> DiscoveryResult:
    """Find every disagreement above the noise floor, give it a verdict, and add what explains it.

    Args:
        train_flights: Flights the effects are fitted and tested on.
        test_flights: Flights the nominal and augmented models are scored on.
        vehicle: Nominal parameters, k_F and k_M as identified (the identify stage's
            ``params.json``, :func:`nanosysid.identify.read_identified`); None: the paper's vehicle
            with k_F and k_M identified on ``train_flights``.
        alpha: Family-wise error rate of each test (see the module's docstring).
        floor: Size a finding needs, in noise floors: the root of its held-out gain per sample.
        share: Share of the generic fit's held-out gain a chosen entry must reach to be kept.
        delays: Delays (s) searched for ``input_delay`` (0 is always tried).
        window, order: Savitzky-Golay window and order of the derivatives and smoothing.
        block: Block length (s); folds: number of folds the blocks are dealt to.
        horizon: Benchmark horizon.
        oracle: A predictor with the true dynamics (simulated data), scored for reference.
        limit: The limit a model of the state can reach: the true dynamics without the effects
            that are not functions of the state (simulated data), scored for reference.
        analysis: Also compute where the models disagree (per channel, regime, band, rollout).
        sindy: Also fit and score the plain SINDy discrepancy model (generic terms only, no names).
    """
    if len(train_flights) < 1:
        raise DataError("discover needs at least 1 training flight")
    # settings that would make every test meaningless (one fold holds nothing out; a block of
    # no length is one sample, and neighbouring samples are not independent)
    for name, value, ok, need in (("folds", folds, isinstance(folds, int) and folds >= 2, "an integer of at least 2"),
                                  ("block", block, np.isfinite(block) and block > 0, "a positive number of seconds"),
                                  ("alpha", alpha, 0 < alpha < 1, "between 0 and 1"),
                                  ("floor", floor, np.isfinite(floor) and floor >= 0, "a number of at least 0"),
                                  ("share", share, 0 <= share <= 1, "between 0 and 1"),
                                  ("window", window, isinstance(window, int) and window > order and window % 2 == 1,
                                   f"an odd integer above the order {order}")):
        if not ok:
            raise ConfigError(f"discover.{name}: {value!r}; it must be {need}")
    _check_excitation(train_flights)
    v = vehicle
    if v is None:
        thrust, yaw = identify(train_flights, Vehicle(), window=window, polyorder=order)
        v = dataclasses.replace(Vehicle(), k_f=thrust.coef, k_m=yaw.coef)
    search = _Search(train_flights, v, window, order, block, folds)
    # the smallest p a one-sided signed-rank test over n blocks gives is 2^-n; with every entry
    # tested at once (Bonferroni) fewer blocks than this could never make a finding
    need = int(np.ceil(np.log2(len(LIBRARY) / alpha)))
    n_blocks = int(search.blocks.max()) + 1
    if n_blocks < need:
        raise DataError(f"discover cannot judge: the training flights make {n_blocks} blocks of {block:g} s, and with "
                        f"{len(LIBRARY)} candidates tested at alpha = {alpha:g} no finding is possible below {need} "
                        f"blocks (about {need * block:g} s of flight); give longer flights, not a verdict of 'nothing'")
    delays = tuple(float(d) for d in delays)
    total = float(search.grams(0.0).et.sum())
    n_samples = len(search.blocks)

    chosen: list[str] = []
    delay = 0.0
    current, _ = search.grams(0.0).heldout(search.cols(chosen))
    rounds: list[list[dict[str, Any]]] = []
    picks: list[dict[str, Any]] = []
    while True:
        options: dict[str, dict[str, Any]] = {}
        g = search.grams(delay)
        for name, c in LIBRARY.items():
            if name in chosen or c is DELAY:
                continue
            sse, thetas = g.heldout(search.cols(chosen + [name]))
            options[name] = {"sse": sse, "thetas": thetas, "delay": delay}
        if delay == 0.0 and delays:
            sse, per_fold = search.nested_delay(chosen, (0.0,) + delays)
            options[DELAY.name] = {"sse": sse, "thetas": per_fold[:, None], "delay": None}
        K = len(options)
        table = []
        for name, o in options.items():
            gains = current - o["sse"]
            z, p = _pvalue(gains)
            size = float(np.sqrt(max(gains.sum(), 0.0) / n_samples))
            o.update(gains=gains, z=z, p=min(1.0, p * K), size=size, sign_ok=_signs_ok(name, o["thetas"], search, chosen))
            o["eligible"] = o["p"] <= alpha and size >= floor and o["sign_ok"]
            table.append({"candidate": name, "heldout_gain": float(gains.sum() / total), "size": size, "z": z, "p": o["p"],
                          "blocks_improved": int((gains > 0).sum()), "blocks": int(len(gains)),
                          "plausible": bool(o["sign_ok"]), "eligible": bool(o["eligible"])})
        table.sort(key=lambda r: -r["heldout_gain"])
        rounds.append(table)
        eligible = [n for n, o in options.items() if o["eligible"]]
        if not eligible:
            break
        best = max(eligible, key=lambda n: options[n]["gains"].sum())
        # the alternatives: eligible entries acting on the same channels that do not explain
        # significantly less (the delay acts on every channel, through the rotor speeds)
        mine = search.touched(best)
        alts = [n for n in eligible if n != best and search.touched(n) & mine
                and _pvalue(options[n]["sse"] - options[best]["sse"])[1] > alpha]
        o = options[best]
        picks.append({"name": best, "round": len(rounds), "alternatives": alts, "heldout_gain": float(o["gains"].sum() / total),
                      "size": o["size"], "z": o["z"], "p": o["p"], "blocks_improved": int((o["gains"] > 0).sum()),
                      "blocks": int(len(o["gains"])),
                      # the rivals the selection chose it over (an implausible or insignificant
                      # candidate is no rival, however much it would fit)
                      "competitors": [n for n in eligible if n != best]})
        if best == DELAY.name:
            delay = _best_delay(search, chosen, (0.0,) + delays)
            current, _ = search.grams(delay).heldout(search.cols(chosen))
        else:
            chosen.append(best)
            current = o["sse"]

    # entries that only correlate with a disagreement outside the library are not named
    generic_cache: dict[tuple, Any] = {}
    kept = []
    for pk in picks:
        if pk["name"] == DELAY.name:
            kept.append(pk)
            continue
        ratio = _explains(search, chosen, pk["name"], delay, generic_cache)
        pk["generic_share"] = ratio
        if ratio >= share:
            kept.append(pk)
    chosen = [pk["name"] for pk in kept if pk["name"] != DELAY.name]
    if not any(pk["name"] == DELAY.name for pk in kept):
        delay = 0.0

    # final coefficients on every block, uncertainty by jackknife over the folds
    g = search.grams(delay)
    cols = search.cols(chosen)
    theta_measured = g.solve(cols)
    g = _true_torque_grams(search, g, chosen, cols, v)
    theta = g.solve(cols)
    _, thetas = g.heldout(cols)
    names = [NOMINAL.name, *chosen]
    coef = split_coefficients(names, theta)
    fold_coef = [split_coefficients(names, t) for t in thetas]
    # the same fit with each plausible rival added (the eligible candidates the selection passed
    # over): a coefficient that moves when a rival joins is uncertain by that much beyond the
    # folds' scatter (collinear or misspecified columns bias it; the folds cannot show a bias)
    rivals = sorted({n for pk in picks for n in pk["competitors"] + [pk["name"]]} - set(chosen) - {DELAY.name})
    rival_coef = []
    for n in rivals:
        alt_cols = search.cols(chosen + [n])
        alt_g = _true_torque_grams(search, search.grams(delay), chosen + [n], alt_cols, v)
        rival_coef.append(split_coefficients(names + [n], alt_g.solve(alt_cols)))
    findings: list[Finding] = []
    named_later = set(chosen) | ({DELAY.name} if delay else set())
    for pk in kept:
        name = pk["name"]
        c = LIBRARY[name]
        if c is DELAY:
            params = {DELAY.params[0]: delay}
            stderr = {DELAY.params[0]: _delay_stderr(search, chosen, (0.0,) + delays)}
            channels = CHANNELS
        else:
            th = np.array(coef[name])
            params = dict(zip(c.params, c.values(th, v)))
            # jackknife of the physical values themselves: the map from the columns' coefficients
            # may be nonlinear (inertia) or mix them (rotor spread)
            se = _jackknife(np.array([c.values(fc[name], v) for fc in fold_coef]))
            stderr = dict(zip(c.params, (float(x) for x in se)))
            channels = _channels_of(search, name, th, delay)
            spread = np.array([list(params.values())] + [c.values(rc[name], v) for rc in rival_coef])
        alts = [a for a in pk["alternatives"] if a not in named_later]
        ev = {k: pk[k] for k in ("round", "heldout_gain", "size", "z", "p", "blocks_improved", "blocks")}
        ev["stderr"] = stderr
        half = {k: _half_width(stderr[k], search.folds) for k in params}
        if c is DELAY:
            ev["ci"] = {k: (params[k] - half[k], params[k] + half[k]) for k in params}
        else:
            ev["rival_range"] = {k: (float(spread[:, i].min()), float(spread[:, i].max())) for i, k in enumerate(params)}
            ev["ci"] = {k: (ev["rival_range"][k][0] - half[k], ev["rival_range"][k][1] + half[k]) for k in params}
        ev["stability"] = _stability(search, chosen, name, pk["competitors"], delay)
        if "generic_share" in pk:
            ev["generic_share"] = pk["generic_share"]
        if alts:
            ev["used"] = name
            ev["separate_by"] = {a: LIBRARY[a].excited_by for a in [name, *alts]}
            findings.append(Finding("ambiguous", None, channels, params, ev, (name, *alts)))
        else:
            findings.append(Finding("named", name, channels, params, ev))

    # what is left: channel by channel, the generic sparse fit
    resid, _ = search.residual(chosen, delay)
    lib, terms = search.terms(delay)
    gains = generic.heldout_gain(terms, resid, search.blocks, g.fold)
    extra_terms: dict[str, float] = {}
    generic_fits: list[tuple[int, np.ndarray]] = []
    state_fit: dict[int, np.ndarray] = {}
    for c in range(6):
        z, p = _pvalue(gains[:, c])
        p = min(1.0, 6 * p)
        size = float(np.sqrt(max(gains[:, c].sum(), 0.0) / n_samples))
        if p > alpha or size < floor:
            continue
        coef_c = generic.sparse_fit(terms, resid[:, [c]])
        raw, shown = generic.terms_of(coef_c, lib, [c], search.weights)
        if not raw:
            continue
        state_fit[c] = terms @ coef_c[0]
        extra_terms.update(raw)
        generic_fits.append((c, coef_c[0] / search.weights[c]))
        findings.append(Finding("unnamed", None, (CHANNELS[c],), shown, {
            "heldout_gain": float(gains[:, c].sum() / total), "size": size, "z": z, "p": p,
            "blocks_improved": int((gains[:, c] > 0).sum()), "blocks": int(len(gains))}))
    # what neither an entry nor the generic terms of the state explain, channel by channel: a
    # residual above the noise floor that no function of the state captures (a disturbance of
    # its own time, say) is said, never left silent
    left = resid - np.column_stack([state_fit.get(c, np.zeros(len(resid))) for c in range(6)])
    findings += _stateless(left, search, alpha, floor, total)
    findings.sort(key=lambda f: -f.evidence["heldout_gain"])

    dk_f, dk_m = coef[NOMINAL.name]
    corrections = {n: LIBRARY[n].values(coef[n], v) for n in chosen if LIBRARY[n].kind == "correction"}
    augmented_vehicle = refitted_vehicle(v, dk_f, dk_m, corrections)
    named_wrench = [n for n in chosen if LIBRARY[n].kind == "wrench"]
    named_values = [x for n in named_wrench for x in coef[n]]
    model = AugmentedPredictor(AugmentedStep(augmented_vehicle, named_wrench + list(extra_terms),
                                             named_values + list(extra_terms.values())), delay=delay, name="discovered")
    if extra_terms and not _stable(model, train_flights, horizon, batch_size):
        # a sparse fit that makes the training rollouts diverge does not join the model
        model = AugmentedPredictor(AugmentedStep(augmented_vehicle, named_wrench, named_values), delay=delay,
                                   name="discovered")
        for f in findings:
            if f.verdict == "unnamed":
                f.evidence["added"] = False
    nominal = AugmentedPredictor(AugmentedStep(v), name="nominal")
    before = benchmark.evaluate(nominal, test_flights, horizon=horizon, batch_size=batch_size)
    after = benchmark.evaluate(model, test_flights, horizon=horizon, batch_size=batch_size)
    ref = benchmark.evaluate(oracle, test_flights, horizon=horizon, batch_size=batch_size) if oracle else None
    result = DiscoveryResult(findings, before, after, model, nominal, augmented_vehicle, rounds, alpha, floor,
                             search.noise, ref)
    if limit is not None:
        result.limit = benchmark.evaluate(limit, test_flights, horizon=horizon, batch_size=batch_size)
    if sindy:
        result.sindy = _sindy_baseline(search, v, test_flights, horizon, batch_size)
    if analysis:
        result.analysis = disagreement(result, search, names, theta_measured, delay, test_flights,
                                       generic_fits=generic_fits, horizon=horizon, batch_size=batch_size)
    return result


def _stable(model: AugmentedPredictor, flights: Sequence[Flight], horizon: int, batch_size: int) -> bool:
    """Whether the model's rollouts stay finite over every window of ``flights``."""
    try:
        benchmark.evaluate(model, flights, horizon=horizon, batch_size=batch_size)
    except PredictionError:
        return False
    return True


def _signs_ok(name: str, thetas: np.ndarray, search: _Search, chosen: list[str]) -> bool:
    """No coefficient with a physical sign is negative by more than two standard errors, and a
    correction stays within its bound of the nominal value."""
    c = LIBRARY[name]
    if c is DELAY:
        return True
    k = len(search.cols(chosen))  # the candidate's columns come last
    th = thetas[:, k:]
    mean, se = th.mean(axis=0), _jackknife(th)
    if any(s > 0 and m < -2 * e for s, m, e in zip(c.signs, mean, se)):
        return False
    if c.bound is not None:
        values = c.values(mean, search.vehicle)
        if any(not np.isfinite(x) or abs(x) > c.bound * abs(n) for x, n in zip(values, c.nominal(search.vehicle))):
            return False
    return True


def _best_delay(search: _Search, chosen: list[str], delays: Sequence[float]) -> float:
    cols = search.cols(chosen)
    sse = {d: search.grams(d).sse(cols, search.grams(d).solve(cols)).sum() for d in delays}
    return min(sse, key=sse.get)


def _delay_stderr(search: _Search, chosen: list[str], delays: Sequence[float]) -> float:
    """Jackknife of the delay over the folds: chosen on all folds but one, in turn."""
    cols = search.cols(chosen)
    picks = []
    for k in range(search.folds):
        train = np.flatnonzero(search.grams(0.0).fold != k)
        sse = {d: search.grams(d).sse(cols, search.grams(d).solve(cols, train), train).sum() for d in delays}
        picks.append(min(sse, key=sse.get))
    return float(_jackknife(np.array(picks)[:, None])[0])


def _stability(search: _Search, chosen: list[str], name: str, competitors: list[str], delay: float) -> float:
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


def _explains(search: _Search, chosen: list[str], name: str, delay: float, cache: dict) -> float:
    """Held-out gain of ``name`` added last, over the generic fit's on the residual without it,
    on the channels it acts on."""
    others = [n for n in chosen if n != name]
    g = search.grams(delay)
    base, _ = g.heldout(search.cols(others), per_channel=True)
    mine, _ = g.heldout(search.cols(others + [name]), per_channel=True)
    own = g.solve(search.cols(others + [name]))[-entry(name).n_columns:]
    channels = [CHANNELS.index(c) for c in _channels_of(search, name, own, delay)]
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


def _sindy_baseline(search: _Search, vehicle: Vehicle, test_flights, horizon, batch_size) -> dict[str, Any]:
    """The plain SINDy discrepancy model: generic sparse terms on the nominal residual, no names."""
    resid, theta = search.residual([], 0.0)
    lib, terms = search.terms(0.0)
    coef = generic.sparse_fit(terms, resid)
    kept, shown = generic.terms_of(coef, lib, range(6), search.weights)
    dk_f, dk_m = theta
    step = AugmentedStep(refitted_vehicle(vehicle, dk_f, dk_m, {}), list(kept),
                         list(kept.values()))
    model = AugmentedPredictor(step, name="sindy")
    try:
        scores = benchmark.evaluate(model, test_flights, horizon=horizon, batch_size=batch_size)
    except PredictionError:  # its rollouts diverge: the plain fit's own failure, recorded as such
        return {"terms": shown, "simerr": {q: math.inf for q in QUANTITIES}, "scores": None, "model": model,
                "diverged": True}
    return {"terms": shown, "simerr": scores.simerr, "scores": scores, "model": model, "diverged": False}
