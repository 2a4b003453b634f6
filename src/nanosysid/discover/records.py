"""Discovery's records: a candidate tried in a round, a pick of the selection, a finding with its
verdict, and the result of a run."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nanosysid import protocol
from nanosysid.discover.model import AugmentedPredictor
from nanosysid.effects import LIBRARY
from nanosysid.vehicle import Vehicle

__all__ = ["VERDICTS", "STATELESS", "UNSTABLE", "UNDETERMINED", "Candidate", "Pick", "Finding", "DiscoveryResult"]

VERDICTS = ("named", "ambiguous", "unnamed", "not a function of the state", "unstable", "undetermined")
STATELESS = VERDICTS[3]
UNSTABLE = VERDICTS[4]
# an entry the search chose whose every coefficient's interval holds zero: the data say something
# of its shape improves the fit, not that the effect is there at any size
UNDETERMINED = VERDICTS[5]


@dataclass
class Candidate:
    """One library entry added to the chosen ones in a round, and the test of its gain.

    Attributes:
        name: The library entry.
        sse: Held-out weighted sum of squares per block ``(B,)`` with it added.
        thetas: The coefficients fitted without each fold ``(folds, P)`` (the delay: each
            fold's delay ``(folds, 1)``).
        gains: The held-out gain per block over the round's start ``(B,)``.
        z, p: The one-sided signed-rank test of the gains (p Bonferroni-adjusted).
        size: The root of its held-out gain per sample, in noise floors.
        heldout_gain: Its gain as a share of the nominal residual's weighted sum of squares.
        plausible: No physical sign or bound is violated.
        eligible: Significant, large enough and plausible.
    """

    name: str
    sse: np.ndarray
    thetas: np.ndarray
    gains: np.ndarray
    z: float
    p: float
    size: float
    heldout_gain: float
    plausible: bool
    eligible: bool

    @property
    def blocks_improved(self) -> int:
        return int((self.gains > 0).sum())

    @property
    def blocks(self) -> int:
        return int(len(self.gains))

    def row(self) -> dict[str, Any]:
        """The round's table row of the report."""
        return {"candidate": self.name, "heldout_gain": self.heldout_gain, "size": self.size, "z": self.z,
                "p": self.p, "blocks_improved": self.blocks_improved, "blocks": self.blocks,
                "plausible": self.plausible, "eligible": self.eligible}


@dataclass
class Pick:
    """A candidate the selection chose.

    Attributes:
        candidate: The chosen candidate of its round.
        round: The round (from 1).
        alternatives: Eligible entries on the same channels it is not significantly better than.
        competitors: The other eligible candidates of its round (an implausible or insignificant
            candidate is no rival, however much it would fit).
        generic_share: Its held-out gain over the generic fit's on the same disagreement (set by
            the pruning; None for the delay).
    """

    candidate: Candidate
    round: int
    alternatives: list[str]
    competitors: list[str]
    generic_share: float | None = None
    history: dict[str, Any] | None = None

    @property
    def name(self) -> str:
        return self.candidate.name

    def evidence(self) -> dict[str, Any]:
        c = self.candidate
        return {"round": self.round, "heldout_gain": c.heldout_gain, "size": c.size, "z": c.z, "p": c.p,
                "blocks_improved": c.blocks_improved, "blocks": c.blocks,
                **({"history": self.history} if self.history is not None else {})}


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
            ``stderr`` (jackknife over the folds) and ``ci`` per coefficient (95 %: the union
            of the chosen fit's interval and each plausible rival fit's, each the folds'
            jackknife with Student's t for one degree of freedom fewer than folds, within the
            entry's physical bound), ``rival_range`` (the values alone),
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
    """What :func:`nanosysid.discover.run` found, and the benchmark scores on the test flights.

    ``rounds`` holds every round's candidates, best held-out gain first."""

    findings: list[Finding]
    before: protocol.Scores
    after: protocol.Scores
    model: AugmentedPredictor
    nominal: AugmentedPredictor
    vehicle: Vehicle
    rounds: list[list[Candidate]]
    alpha: float
    floor: float
    noise: np.ndarray
    oracle: protocol.Scores | None = None
    sindy: dict[str, Any] | None = None
    analysis: dict[str, Any] = field(default_factory=dict)
    limit: protocol.Scores | None = None
    # the true dynamics of the state with the angular velocity held (dω/dt = 0): the limit of a
    # model on the paper's physics model's base
    held_limit: protocol.Scores | None = None
    # entries the selection chose and the reference checks dropped (select.check_reference)
    dropped: list[dict[str, Any]] = field(default_factory=list)
    # one row per training flight left out (nanosysid.discover.stability)
    folds: list[dict[str, Any]] = field(default_factory=list)
    # the runs of one reference found among the training flights, in words
    pairs: str = ""
    # k_M given, whether it was held, and the least-squares refit beside
    k_m: dict[str, Any] = field(default_factory=dict)
    # the paper's physics model (the nominal vehicle, dω/dt = 0) on the test flights
    held_rate: protocol.Scores | None = None
    # why the augmented model's rollouts on the test flights are not finite (its scores are then
    # infinite), where the caller accepts that; None where they are
    diverged: str | None = None
    # the axes whose torque equation the model integrates, and the held-out rollouts of the
    # training flights that chose them and the generic terms (nanosysid.discover.assemble)
    base: dict[str, Any] = field(default_factory=dict)

    @property
    def best_nominal(self) -> dict[str, float]:
        """Per quantity, the lower SimErr on the test flights of the two nominal rows: physics_full
        (the torque equation integrated) and the paper's physics (dω/dt = 0), the row a gain is
        measured against."""
        rows = [self.before.simerr] + ([self.held_rate.simerr] if self.held_rate is not None else [])
        return {k: float(min(r[k] for r in rows)) for k in self.before.simerr}

    @property
    def found(self) -> list[Finding]:
        """The findings with verdict ``"named"``."""
        return [f for f in self.findings if f.verdict == "named"]

    @property
    def name(self) -> str:
        """``physics+<entries>``: every library entry the augmented model applies (the named,
        ambiguous and undetermined findings'; an unstable one is left out of the model), and
        ``terms`` where it applies generic terms (an unnamed finding's are left out where they
        would make the training rollouts diverge, or where it is no fit of the state)."""
        terms = [f for f in self.unnamed if f.evidence.get("added", True)]
        parts = [f.entry for f in self.findings if f.entry and f.verdict in ("named", "ambiguous", "undetermined")]
        parts += ["terms"] if terms else []
        return "+".join(["physics"] + parts)

    @property
    def unnamed(self) -> list[Finding]:
        return [f for f in self.findings if f.verdict == "unnamed"]
