"""The take-off hold of a rig's log: the seconds the vehicle flies before its reference starts
moving, outside the scored segment (:func:`nanosysid.rig.logs.trajectory_segment`).

In a hold the controller trims the rotors against whatever constant torque acts, so the hold
measures a centre-of-mass offset flight by flight (:func:`nanosysid.hypotheses.hold_offset`):
it moves when the battery is re-seated between flights.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nanosysid.dataio import Flight
from nanosysid.errors import DataError
from nanosysid.rig.logs import LogSpec, _runs, read_log, trajectory_segment

__all__ = ["HOLD_HEIGHT", "take_off_hold"]

# m: the hold's samples start above this height (clear of the floor's ground effect, off the
# landing gear's contact)
HOLD_HEIGHT = 0.3


def take_off_hold(path: str | Path, spec: LogSpec, name: str, *, height: float = HOLD_HEIGHT) -> Flight:
    """The take-off hold of the log at ``path`` as a :class:`~nanosysid.dataio.Flight` named
    ``name``: the rows of the flight's longest flying run before its segment starts, above
    ``height``, with every rotor-speed reading valid; the onboard state as outputs (position,
    velocity, quaternion xyzw, body rates) and the rotor speeds (rad/s) as inputs, on the logs'
    own grid.

    Raises:
        DataError: the log holds fewer than 20 such rows (naming the log).
    """
    df, _ = read_log(Path(path), spec.aliases)
    where = str(path)
    start, _, _ = trajectory_segment(df, where)
    flying = df["is_flying"].to_numpy().astype(bool)
    first = start
    while first > 0 and flying[first - 1]:
        first -= 1
    rows = np.arange(first, start)
    erpm = df[["m1_erpm", "m2_erpm", "m3_erpm", "m4_erpm"]].to_numpy(dtype=np.float64)[rows]
    y = df[["x", "y", "z", "vx", "vy", "vz", "qx", "qy", "qz", "qw", "wx", "wy", "wz"]].to_numpy(dtype=np.float64)[rows]
    ok = (np.isfinite(erpm).all(axis=1) & (erpm <= spec.max_erpm).all(axis=1) & np.isfinite(y).all(axis=1)
          & (y[:, 2] > height))
    # the hold's longest run of valid rows: the derivatives need consecutive samples
    runs = _runs(ok)
    if not runs or max(b - a for a, b in runs) < 20:
        raise DataError(f"{where}: columns 'is_flying z m1_erpm..m4_erpm': fewer than 20 valid rows of take-off hold "
                        f"above {height:g} m before the flight segment")
    a, b = max(runs, key=lambda r: r[1] - r[0])
    t = df["t"].to_numpy(dtype=np.float64)[rows][a:b]
    return Flight(name, t - t[0], erpm[a:b] * spec.rads_per_erpm, y[a:b])
