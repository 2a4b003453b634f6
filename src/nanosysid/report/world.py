"""The simulated world in the reports: its effects as tables (the compare report's, with their
strengths in the dataset, and the README's, with the library entries that describe each) and
nature's own thrust coefficient from the simulator's direct output."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from nanosysid.dataio import read_flight_csv
from nanosysid.sim.simulator import collective_thrust_coefficient
from nanosysid.sim.world import REGISTRY

__all__ = ["world_markdown", "readme_table", "nature_thrust_coefficient"]


def world_markdown(strengths: Mapping[str, float]) -> str:
    """The simulated world's effects: strength in this dataset, what each does, what it depends on."""
    L = ["## The simulated world", "",
         "Effects of nature in this dataset (`sim.effects`; 1.0 is a realistic magnitude, 0 off). Only the ones that "
         "depend on the state and the rotor speeds can a model learn; the turbulence is new in every flight.", "",
         "| effect | strength | default world | depends on | what it does |", "|---|---|---|---|---|"]
    for e in REGISTRY.values():
        L.append(f"| `{e.name}` | {float(strengths.get(e.name, 0.0)):g} | {e.default:g} | {e.depends_on} | "
                 f"{e.description} |")
    return "\n".join(L) + "\n"


def readme_table() -> str:
    """The README's world table: each effect, what it does and depends on, whether the default
    world has it, and the library entries that describe it (the campaign's judge)."""
    L = ["| world effect | what it does | depends on | in the default world | library entry |", "|---|---|---|---|---|"]
    for e in REGISTRY.values():
        entries = (", ".join(f"`{n}`" for n in sorted(e.described_by)) if e.described_by
                   else "none: no model of the state can know it")
        L.append(f"| `{e.name}` | {e.summary} | {e.depends_on} | {'yes' if e.default else 'no'} | {entries} |")
    return "\n".join(L)


def nature_thrust_coefficient(direct_dir: Path, names: list[str]) -> float | None:
    """:func:`~nanosysid.sim.simulator.collective_thrust_coefficient` of the flights ``names`` of
    the simulator's direct output (None where they are not there)."""
    files = [Path(direct_dir) / f"{n}.csv" for n in names]
    if not names or not all(f.exists() for f in files):
        return None
    return collective_thrust_coefficient([read_flight_csv(f) for f in files])
