"""The room a simulated flight stays in, and what the simulate stage refuses to record.

A world whose effects overpower the controller (``sim.effects.turbulence: 50``), or gains that
destabilise it, still integrates: the vehicle falls through the floor and on, and the flight would
enter the benchmark as data that no vehicle gives. A real flight ends at the floor or the net; a
simulated one that leaves the room is refused, naming the flight, the time and the place.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from nanosysid.dataio import Flight
from nanosysid.errors import ConfigError

__all__ = ["FLOOR", "ROOM", "check_flown"]

FLOOR = 0.0  # m, the world z of the floor (the trajectories fly at 1 to 2 m)
ROOM = 10.0  # m, the half-width of the room about the origin and its height


def _leaves(y: np.ndarray) -> np.ndarray:
    """Per sample of a flight's outputs ``(N, 13)``, whether the vehicle is out of the room (or
    its state is no number)."""
    p = y[:, :3]
    with np.errstate(invalid="ignore"):
        return (~np.isfinite(y).all(axis=1) | (p[:, 2] < FLOOR) | (p[:, 2] > ROOM)
                | (np.abs(p[:, :2]) > ROOM).any(axis=1))


def check_flown(flights: Sequence[Flight], settings: str) -> None:
    """Refuse the first flight that leaves the room (below the floor, beyond :data:`ROOM`, or a
    state that is not finite), naming ``settings``, the settings that made it."""
    for f in flights:
        out = _leaves(f.y)
        if out.any():
            i = int(np.argmax(out))
            x, y, z = f.y[i, :3]
            where = ("its state is not finite" if not np.isfinite(f.y[i]).all() else
                     f"it is below the floor (z = {z:.2f} m)" if z < FLOOR else
                     f"it has left the room (x, y, z = {x:.1f}, {y:.1f}, {z:.1f} m; the room is "
                     f"{2 * ROOM:g} m wide and {ROOM:g} m high)")
            raise ConfigError(f"{f.name}: at t = {f.t[i]:.2f} s of the simulated flight {where}: the controller "
                              f"lost the vehicle; {settings} are beyond what it flies")
