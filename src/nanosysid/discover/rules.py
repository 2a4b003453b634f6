"""The rules every verdict of discovery obeys (docs/discovery.md), checked on a discovery record
(the ``result.json`` the discover stage writes), not on the report's wording.

Example::

    import json
    from nanosysid.discover.rules import violations

    violations(json.loads(open("reports/discovery/result.json").read()))   # [] when every rule holds
"""

from __future__ import annotations

from typing import Any, Mapping

from nanosysid.discover.sources import REPEATS
from nanosysid.discover.stability import HOLD
from nanosysid.discover.verdicts import STATELESS_FLOOR
from nanosysid.effects import DELAY, LIBRARY
from nanosysid.vehicle import Vehicle

__all__ = ["violations"]

IN_MODEL = ("named", "ambiguous", "undetermined")  # the verdicts whose entry the augmented model applies


def _entry(f: Mapping[str, Any]) -> str | None:
    return f["name"] or (f["alternatives"][0] if f["alternatives"] else None)


def _holds_zero(ci: Mapping[str, Any]) -> bool:
    return bool(ci) and all(lo <= 0.0 <= hi for lo, hi in ci.values())


def violations(record: Mapping[str, Any]) -> list[str]:
    """Every rule a record's verdicts break, one line each (empty: all hold).

    - a verdict reached on fewer than :data:`~nanosysid.discover.stability.HOLD` of the folds that
      leave one training flight out is ``unstable``, and only such a one;
    - a finding the model applies passed the selection's test (``p`` at most ``alpha``, size at
      least ``floor`` noise floors), and an ambiguous one has at least two rivals;
    - a named finding has a coefficient whose 95 % interval excludes zero; an ``undetermined``
      one has none (the delay, whose interval starts at zero by construction, aside);
    - an entry the model applies has coefficients physics allows it: within its bound, of the
      shape physics gives them together (a slow actuation's is a lag:
      :meth:`~nanosysid.effects.Effect.implausible_values`);
    - a residual called not a function of the state is at least the noise floor in size and
      does not mostly repeat with the reference;
    - the augmented model's name lists exactly the named, ambiguous and undetermined findings'
      entries (an unstable one, which rests on some of the flights only, is left out).
    """
    out: list[str] = []
    alpha, floor = float(record["alpha"]), float(record["floor"])
    vehicle = Vehicle(**{k: tuple(v) if isinstance(v, list) else v for k, v in record["vehicle"].items()})
    parts = record["model"].split("+")[1:]
    model = set(parts) - {"terms"}
    for i, f in enumerate(record["findings"]):
        v, ev, entry = f["verdict"], f["evidence"], _entry(f)
        what = f"finding {i + 1} ({v}{' `' + entry + '`' if entry else ''} on {', '.join(f['channels'])})"
        folds = ev.get("folds")
        if folds and folds["of"]:
            stable = folds["held"] >= HOLD * folds["of"]
            if stable and v == "unstable":
                out.append(f"{what}: reached on {folds['held']} of {folds['of']} flight folds, at least "
                           f"{HOLD:.0%}, yet unstable")
            if not stable and v != "unstable":
                out.append(f"{what}: reached on only {folds['held']} of {folds['of']} flight folds, below "
                           f"{HOLD:.0%}, yet not unstable")
        if v in IN_MODEL:
            if float(ev["p"]) > alpha:
                out.append(f"{what}: p = {ev['p']:.3g} above alpha = {alpha:g}")
            if float(ev["size"]) < floor:
                out.append(f"{what}: size {ev['size']:.3g} noise floors, below the floor {floor:g}")
            if entry not in model:
                out.append(f"{what}: its entry is not in the model {record['model']}")
            why = (LIBRARY[entry].implausible_values(list(f["params"].values()), vehicle)
                   if entry in LIBRARY and f["params"] else "")
            if why:
                out.append(f"{what}: not physically possible as `{entry}`: {why}")
        if v == "ambiguous" and len(f["alternatives"]) < 2:
            out.append(f"{what}: ambiguous with fewer than two rivals")
        if v == "named" and entry != DELAY.name and _holds_zero(ev.get("ci") or {}):
            out.append(f"{what}: named, but every coefficient's interval holds zero")
        if v == "undetermined" and not _holds_zero(ev.get("ci") or {}):
            out.append(f"{what}: undetermined, but a coefficient's interval excludes zero")
        if v == "unstable" and entry and entry in model:
            out.append(f"{what}: unstable, yet its entry is in the model {record['model']}")
        if v == "not a function of the state":
            if float(ev["size"]) < STATELESS_FLOOR:
                out.append(f"{what}: size {ev['size']:.3g} noise floors, below {STATELESS_FLOOR:g}")
            if (ev.get("source") or {}).get("source") == REPEATS:
                out.append(f"{what}: it repeats with the reference, which makes it unnamed")
    entries = {_entry(f) for f in record["findings"] if f["verdict"] in IN_MODEL}
    for name in sorted(model - entries):
        out.append(f"the model {record['model']} applies `{name}`, which no named, ambiguous or undetermined "
                   "finding gives")
    return out
