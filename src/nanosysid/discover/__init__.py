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
given). The search judges every candidate with k_F and k_M refitted alongside it (least
squares, a nuisance fit: a candidate is credited with what it adds, not with the closed-loop
bias of k_M); the augmented model and every coefficient it reports hold the identify stage's
k_F and k_M (``hold_nominal``), and the least-squares k_M is reported beside them. **The candidates**
are the library of :mod:`nanosysid.effects` (knowledge from the literature, several forms of one
effect where the literature has several, the actuation's lag and battery, and corrections of
the nominal mass, inertia and arm); this package never imports the simulator's world.

**The rule.** Residuals are weighted by their noise floor (:func:`~nanosysid.discover.fit.noise_parts`,
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

**History and time.** A chosen entry is kept only if its fit repeats with the reference, its
instrumental estimate (the partner run's columns) agreeing with least squares; an entry of the
rotor speeds' history also only if, added to every state entry of the library at once, it still
passes the selection's test (:func:`~nanosysid.discover.select.check_reference`). A residual
that stays above the noise after every state entry and the generic terms is **not a function of
the state** when it does not repeat between runs of one reference (a function of time); when it
does repeat, it follows the reference through the state or the input history, which no test
here tells apart, and it is **unnamed** (:func:`~nanosysid.discover.verdicts.stateless`).
An onboard velocity estimate's slow drift, through the drag columns, makes such a residual of
time too; ``velocity="position"`` has the regressors read the recorded position's derivative
instead (a motion-capture position has no such drift).

**The numbers of a finding.** Its coefficients are fitted on every block, in the true body's
units: where the inertia correction is chosen, every other torque column is scaled by
``J / (J + dJ)`` and refitted until ``dJ`` settles, so k_M, a rotor inertia or a damping is the
one the augmented model (which integrates with ``J + dJ``) must apply. Their 95 % intervals
take both kinds of uncertainty: the folds' scatter (a delete-a-fold jackknife of the physical
values, Student's t for the folds' number) of the chosen fit and of each fit with a plausible
rival joined (an eligible candidate the selection passed over, or one it found too small), the
union of them all, within the entry's physical bound. The folds alone cannot show a bias: a
collinear or missing column moves a coefficient the same way in every fold. With the inertia
correction chosen, the fits with the yaw inertia held at each end of its plausible range are
rivals too. Its stability is the share of the folds on which it beats, held out, every other
eligible candidate of its round.

**The phases**, each its own module: the regression data, noise floor, blocks and folds
(:mod:`~nanosysid.discover.search`, over :mod:`~nanosysid.discover.fit`); the candidate search
and its pruning (:mod:`~nanosysid.discover.select`); the coefficients, verdicts and intervals
(:mod:`~nanosysid.discover.verdicts`); the augmented model (:mod:`~nanosysid.discover.assemble`);
where the models disagree (:mod:`~nanosysid.discover.analysis`). Their records (a candidate, a
pick, a finding, the result) are in :mod:`~nanosysid.discover.records`.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from nanosysid import protocol
from nanosysid.dataio import Flight, check_distinct, flight_list
from nanosysid.discover.analysis import disagreement
from nanosysid.discover.assemble import assemble, sindy_baseline
from nanosysid.discover.fit import VELOCITIES, ChainFilter, with_position_velocity
from nanosysid.discover.model import AugmentedPredictor, AugmentedStep
from nanosysid.discover.records import STATELESS, UNDETERMINED, UNSTABLE, VERDICTS, Candidate, DiscoveryResult, Finding, Pick
from nanosysid.discover.search import Search
from nanosysid.discover import stability
from nanosysid.discover.select import check_reference, prune, select
from nanosysid.discover.sources import reference_pairs
from nanosysid.discover.verdicts import coefficients, named, stateless, undetermined, unnamed
from nanosysid.effects import CHANNELS, DELAY, LIBRARY
from nanosysid.errors import ConfigError, DataError, PredictionError
from nanosysid.identify import identify
from nanosysid.metrics import QUANTITIES
from nanosysid.models.physics import PhysicsStep
from nanosysid.rollout import StepPredictor
from nanosysid.vehicle import Vehicle

__all__ = ["run", "Finding", "DiscoveryResult", "Candidate", "Pick", "VERDICTS", "STATELESS", "UNSTABLE", "UNDETERMINED", "CHANNELS",
           "LIBRARY",
           "MIN_TRAVEL", "MIN_RATE"]


# training flights that move less than this (RMS distance from each flight's mean position, m,
# and RMS angular rate, rad/s) excite no effect of the library: drags need speed, gyroscopic and
# inertia terms need rates (a speed's RMS would not do: a hover's measured velocity is mostly
# the estimator's drift). A hover in turbulent air turns at about 0.2 rad/s RMS, the controller
# answering the air; the slowest flight of the benchmark's trajectories at about 0.6.
MIN_TRAVEL, MIN_RATE = 0.05, 0.4


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
        oracle: Any = None, limit: Any = None, held_limit: Any = None, analysis: bool = True, sindy: bool = False,
        inertia_z_range: tuple[float, float] | None = None, batch_size: int = 8192, flights_out: bool = False,
        hold_k_m: bool = False, hold_nominal: bool = True, progress: bool = False, diverged_ok: bool = False,
        velocity: str = "position", chain: ChainFilter | None = None,
        noise_draws: int = 4) -> DiscoveryResult:
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
        held_limit: The limit of a model that holds the angular velocity as the paper's physics
            model does: ``limit`` with ``dw/dt = 0`` (simulated data), scored for reference.
        analysis: Also compute where the models disagree (per channel, regime, band, rollout).
        sindy: Also fit and score the plain SINDy discrepancy model (generic terms only, no names).
        inertia_z_range: The yaw inertia's plausible range (kg m²): the yaw inertia correction's
            interval reaches all of it (the flights tell yaw ratios to J_z, not J_z).
        flights_out: Also run the search without each training flight in turn
            (:mod:`nanosysid.discover.stability`): fold stability, intervals from flights, and
            the verdict ``unstable`` for one that holds on too few folds (it then leaves the
            augmented model).
        hold_k_m: Hold k_M at the given vehicle's instead of refitting it with every candidate.
            Refitting (the default) is least squares on closed-loop flights, which the identify
            stage's instrumental variables avoid; holding leaves every effect that bends the
            yaw torque's relation to the rotor speeds (a lag of the rotors' wrench) to be fitted
            against a k_M estimated without it, which on simulated worlds with such a lag keeps
            the lag from being named. Both values are reported.
        hold_nominal: Hold k_F and k_M at the given vehicle's in the model's fits (its
            coefficients, their intervals, the generic terms) while the search still refits
            them alongside each candidate: the model and the identify stage then agree on both,
            and a least-squares k_M, biased on closed-loop flights, enters no prediction.
        progress: A progress bar over those folds.
        diverged_ok: Where the augmented model's rollouts on the test flights are not finite,
            return the verdicts with infinite scores and the reason in ``diverged`` instead of
            raising :class:`~nanosysid.errors.PredictionError` (a campaign judges the verdicts
            of every world).
        velocity: The body velocity every regressor reads on ``train_flights``: the recorded one
            (``estimate``) or the derivative of the recorded position (``position``; with a
            motion-capture position, free of an onboard estimate's slow drift:
            :func:`~nanosysid.discover.fit.with_position_velocity`). The test flights are scored
            as recorded either way.
        chain: The zero-phase Butterworth low-passes the data chain ran the accelerometer,
            the gyro and the rotor speeds through (None: none): the shape of their noise.
        noise_draws: Draws of noise like the rotor speeds' own that measure what it does to
            the normal equations, taken out of them (errors in variables: the same noise is in
            the residual and in every column made of the speeds); 0 leaves it in.
    """
    train_flights = given = flight_list(train_flights, "discover.run", "train_flights")
    test_flights = flight_list(test_flights, "discover.run", "test_flights")
    if len(train_flights) < 1:
        raise DataError("discover needs at least 1 training flight")
    if not test_flights:
        raise DataError("discover.run: test_flights is empty; the nominal and augmented models are scored on them")
    bad = [d for d in delays if isinstance(d, bool) or not isinstance(d, (int, float, np.integer, np.floating))
           or not np.isfinite(d) or d < 0]
    if bad:
        raise ConfigError(f"discover.run: delays must be finite numbers of seconds >= 0 (a rotor speed is recorded "
                          f"after it acts, never before), got {bad[0]!r}")
    _check_settings(folds=folds, block=block, alpha=alpha, floor=floor, share=share, window=window, order=order)
    if velocity not in VELOCITIES:
        raise ConfigError(f"discover: velocity must be one of {', '.join(VELOCITIES)}, got {velocity!r}")
    _check_excitation(train_flights)
    if velocity == "position":
        train_flights = [with_position_velocity(f, window, order) for f in train_flights]
    v = vehicle
    if v is None:
        thrust, yaw = identify(train_flights, Vehicle(), window=window, polyorder=order)
        v = dataclasses.replace(Vehicle(), k_f=thrust.coef, k_m=yaw.coef)
    search = Search(train_flights, v, window, order, block, folds, hold_k_m=hold_k_m and vehicle is not None,
                    hold_nominal=hold_nominal and vehicle is not None, chain=chain,
                    noise_draws=noise_draws)
    _check_blocks(search, alpha, block)
    check_distinct([*given, *test_flights])  # a flight fitted on is no test of the fit
    delays = tuple(float(d) for d in delays)
    total = float(search.grams(0.0).et.sum())

    pairs = reference_pairs(search.flights, [d.t for d in search.data(0.0)])
    selection = prune(search, select(search, delays, alpha=alpha, floor=floor, total=total), share)
    selection = check_reference(search, selection, pairs, alpha=alpha, floor=floor)
    fit = coefficients(search, selection, v, inertia_z_range)
    findings = named(search, selection, fit, v, delays, inertia_z_range)
    rest = unnamed(search, selection, alpha=alpha, floor=floor, total=total)
    findings += rest.findings
    # a residual above the noise floor that no function of the state captures (a disturbance of
    # its own time, say) is said, never left silent
    findings += stateless(rest.left, search, alpha, floor, total, pairs, selection.delay)
    findings.sort(key=lambda f: -f.evidence["heldout_gain"])
    folds_out = []
    if flights_out and len(train_flights) >= 3:
        folds_out = stability.leave_one_flight_out(search, selection, v, delays, alpha=alpha, floor=floor,
                                                   share=share, progress=progress)
        stability.apply(findings, folds_out, search, selection)
    undetermined(findings)
    selection, fit, terms, fits = _without_unstable(findings, search, selection, fit, rest, v, inertia_z_range)
    model, augmented_vehicle, base = assemble(v, selection.chosen, fit.coef, selection.delay, terms, findings,
                                              search, fit.per_fold, fits, horizon=horizon, batch_size=batch_size)

    nominal = AugmentedPredictor(AugmentedStep(v), name="nominal")

    def score(predictor):
        return protocol.evaluate(predictor, test_flights, horizon=horizon, batch_size=batch_size)

    diverged = None
    try:
        after = score(model)
    except PredictionError as e:
        if not diverged_ok:
            raise
        after, diverged = protocol.Scores({q: np.full(horizon, np.inf) for q in QUANTITIES}, 0), str(e)
    result = DiscoveryResult(findings, score(nominal), after, model, nominal, augmented_vehicle,
                             selection.rounds, alpha, floor, search.noise, score(oracle) if oracle else None)
    result.diverged = diverged
    result.base = base
    # the paper's physics model on the same nominal vehicle: the angular velocity held (dω/dt = 0)
    result.held_rate = score(StepPredictor(PhysicsStep(v, dt=nominal.step.dt, angular_dynamics=False), name="physics"))
    result.dropped = [{"entry": pk.name, "history": pk.history} for pk in selection.dropped]
    result.folds = folds_out
    result.pairs = pairs.described([f.name for f in search.flights])
    result.k_m = {"given": float(v.k_m), "held": bool(search.hold_k_m or search.hold_nominal),
                  "searched_with": "given" if search.hold_k_m else "least squares",
                  "least_squares": float(v.k_m + search.free_k_m(selection.chosen, selection.delay))}
    if limit is not None:
        result.limit = score(limit)
    if held_limit is not None:
        result.held_limit = score(held_limit)
    if sindy:
        result.sindy = sindy_baseline(search, v, test_flights, horizon, batch_size)
    if analysis and diverged is None:
        result.analysis = disagreement(result, search, fit.names, fit.measured, selection.delay, test_flights,
                                       generic_fits=rest.fits, horizon=horizon, batch_size=batch_size,
                                       partners=pairs.partners)
    return result


def _without_unstable(findings: Sequence[Finding], search: Search, selection, fit, rest, vehicle: Vehicle,
                      inertia_z_range) -> tuple[Any, Any, dict[str, float], list]:
    """The selection, its fit and the generic terms without what rests on some of the training
    flights only: an unstable entry leaves the augmented model and its name, and so do the
    generic terms of an unstable unnamed channel. The kept entries are fitted again without the
    ones left out, and their findings take the refitted values (their intervals, from fits that
    had the left-out entry as one more column, stay as wide). An undetermined entry stays: every
    flight carries it, and its fit is the best estimate even where its interval cannot exclude
    zero."""
    out = {f.entry for f in findings if f.verdict == UNSTABLE and f.entry}
    channels = {c for f in findings if f.verdict == UNSTABLE and f.evidence.get("was") == "unnamed"
                and not f.evidence.get("repeats") for c in f.channels}
    terms = {k: x for k, x in rest.terms.items() if k.split(":")[1] not in channels}
    fits = [(c, a) for c, a in rest.fits if CHANNELS[c] not in channels]
    if not out:
        return selection, fit, terms, fits
    kept = dataclasses.replace(selection, chosen=[n for n in selection.chosen if n not in out],
                               delay=0.0 if DELAY.name in out else selection.delay)
    fit = coefficients(search, kept, vehicle, inertia_z_range)
    for f in findings:
        if f.verdict in ("named", "ambiguous") and f.entry in kept.chosen:
            e = LIBRARY[f.entry]
            f.params = dict(zip(e.params, (float(x) for x in e.values(fit.coef[f.entry], vehicle))))
    return kept, fit, terms, fits


def _check_settings(*, folds, block, alpha, floor, share, window, order) -> None:
    """Refuse the settings that would make every test meaningless (one fold holds nothing out; a
    block of no length is one sample, and neighbouring samples are not independent)."""
    for name, value, ok, need in (("folds", folds, isinstance(folds, int) and folds >= 2, "an integer of at least 2"),
                                  ("block", block, np.isfinite(block) and block > 0, "a positive number of seconds"),
                                  ("alpha", alpha, 0 < alpha < 1, "between 0 and 1"),
                                  ("floor", floor, np.isfinite(floor) and floor >= 0, "a number of at least 0"),
                                  ("share", share, 0 <= share <= 1, "between 0 and 1"),
                                  ("window", window, isinstance(window, int) and window > order and window % 2 == 1,
                                   f"an odd integer above the order {order}")):
        if not ok:
            raise ConfigError(f"discover.{name}: {value!r}; it must be {need}")


def _check_blocks(search: Search, alpha: float, block: float) -> None:
    """Refuse to judge too few blocks: the smallest p a one-sided signed-rank test over n blocks
    gives is 2^-n, so with every entry tested at once (Bonferroni) fewer blocks than
    log2(candidates / alpha) could never make a finding."""
    need = int(np.ceil(np.log2(len(LIBRARY) / alpha)))
    n_blocks = int(search.blocks.max()) + 1
    if n_blocks < need:
        raise DataError(f"discover cannot judge: the training flights make {n_blocks} blocks of {block:g} s, and with "
                        f"{len(LIBRARY)} candidates tested at alpha = {alpha:g} no finding is possible below {need} "
                        f"blocks (about {need * block:g} s of flight); give longer flights, not a verdict of 'nothing'")
