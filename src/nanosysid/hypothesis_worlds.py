"""The hypothesis tests (:mod:`nanosysid.hypotheses`) judged on simulated worlds whose truth is
hidden from them.

Three families of worlds, each with one of nature's effects alone (strength log-uniform in 0.3 to
3 times its record's, seeds drawn from one seed), every training trajectory flown twice: a
centre-of-mass offset (the tests must name ``cg_offset``), turbulence (the arena's air, a new
realisation every flight: they must not name a centre-of-mass offset) and the rotors' drag at
their hubs above the centre of mass (a drag moment: they must not call it a centre-of-mass
offset). This module is the judge: it knows the worlds; the tests see only the flights.

Example::

    worlds = draw({"com_offset": 20, "turbulence": 20, "rotor_drag": 20}, seed=0)
    rows = check(worlds, cfg=campaign.short_flights_config(20.0), vehicle=Vehicle())
    summarize(rows)["families"]["com_offset"]["met_share"]
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from nanosysid import hypotheses, sim
from nanosysid.sim import SimConfig
from nanosysid.sim import world as nature
from nanosysid.vehicle import Vehicle

__all__ = ["FAMILIES", "HypothesisWorld", "draw", "check", "summarize"]

# family (the one effect of nature its worlds hold) -> the verdict the tests must reach on it
FAMILIES = {"com_offset": "named cg_offset", "turbulence": "no cg_offset", "rotor_drag": "no cg_offset"}
STRENGTHS = (0.3, 3.0)
TRAIN = ("square", "random", "chirp")


@dataclass(frozen=True)
class HypothesisWorld:
    """One world: its family (the one effect of nature it holds), the effect's strength, its seed."""

    index: int
    family: str
    strength: float
    seed: int


def draw(counts: Mapping[str, int], seed: int = 0) -> list[HypothesisWorld]:
    """``counts[family]`` worlds of each family of :data:`FAMILIES`, drawn from ``seed``."""
    rng = np.random.default_rng([seed, 11])
    out = []
    for family, n in counts.items():
        if family not in FAMILIES:
            raise ValueError(f"family {family!r}; the families are {', '.join(FAMILIES)}")
        for _ in range(int(n)):
            s = float(f"{math.exp(rng.uniform(math.log(STRENGTHS[0]), math.log(STRENGTHS[1]))):.3g}")
            out.append(HypothesisWorld(len(out), family, s, int(rng.integers(1, 2**31 - 1))))
    return out


def _truth(world: HypothesisWorld, vehicle: Vehicle) -> list[float] | None:
    rec = nature.REGISTRY[world.family]
    if rec.truth is None or rec.truth[0] != "cg_offset":
        return None
    return [float(v) for v in rec.truth[1](world.strength, vehicle)]


def check(worlds: Sequence[HypothesisWorld], *, cfg: SimConfig, vehicle: Vehicle, cutoff: float = hypotheses.CUTOFF,
          window: int = 15, order: int = 3, chunk: int = 6, progress: bool = False) -> list[dict[str, Any]]:
    """Every world's training flights (each trajectory of :data:`TRAIN` flown twice), the tests on
    them with ``vehicle`` as the nominal model, and the judge's row: what was named, and for a
    centre-of-mass world whether the ``cg_offset`` interval from the flights covers the truth."""
    from tqdm.auto import tqdm

    rows = []
    bar = tqdm(total=len(worlds), desc="hypothesis worlds", unit="world", disable=not progress)
    for k in range(0, len(worlds), chunk):
        part = worlds[k:k + chunk]
        specs = [sim.FlightSpec(trajectory=tr, run=run, effects={w.family: w.strength}, seed=w.seed,
                                name=f"{tr}_w{w.index}_run{run}")
                 for w in part for tr in TRAIN for run in (1, 2)]
        flights = sim.simulate_flights(specs, cfg=cfg, vehicle=vehicle, progress=False)
        per = 2 * len(TRAIN)
        for i, w in enumerate(part):
            own = flights[per * i:per * (i + 1)]
            data = hypotheses.torque_data(own, vehicle, window=window, order=order, cutoff=cutoff)
            result = hypotheses.tested_apart(data, hypotheses.reference_correlation(own, data), vehicle=vehicle)
            cg = result["hypotheses"]["cg_offset"]
            truth = _truth(w, vehicle)
            covered = None
            if truth is not None:
                covered = bool(all(abs(m - t) <= h for m, h, t in zip(cg["mean"], cg["half_width"], truth)))
            rows.append({"world": w.index, "family": w.family, "strength": w.strength, "seed": w.seed,
                         "named": result["named"],
                         "status": {n: r["status"] for n, r in result["hypotheses"].items()},
                         "share": {n: r.get("share") for n, r in result["hypotheses"].items()},
                         "cg_offset": {"mean": cg["mean"], "half_width": cg["half_width"], "truth": truth,
                                       "covered": covered},
                         "residual_repeats": result["repeats"]["residual"]})
            bar.update()
    bar.close()
    return rows


def summarize(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per family: the worlds, what the tests named (counts), the share of worlds that meet the
    family's requirement of :data:`FAMILIES`, and for the centre-of-mass worlds the coverage of
    the ``cg_offset`` interval."""
    out: dict[str, Any] = {}
    for family, requirement in FAMILIES.items():
        own = [r for r in rows if r["family"] == family]
        if not own:
            continue
        names: dict[str, int] = {}
        for r in own:
            for n in r["named"] or ["nothing"]:
                names[n] = names.get(n, 0) + 1
        cg = [("cg_offset" in r["named"]) for r in own]
        met = cg if requirement == "named cg_offset" else [not c for c in cg]
        rec = {"worlds": len(own), "requirement": requirement, "met": int(sum(met)), "met_share": sum(met) / len(own),
               "named": dict(sorted(names.items()))}
        cover = [r["cg_offset"]["covered"] for r in own if r["cg_offset"]["covered"] is not None]
        if cover:
            rec["coverage"] = {"covered": int(sum(cover)), "worlds": len(cover), "share": sum(cover) / len(cover)}
        out[family] = rec
    return {"families": out, "worlds": len(rows)}
