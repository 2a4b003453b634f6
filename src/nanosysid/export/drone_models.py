"""The identified vehicle as a drone-models parameter file.

drone-models (utiasDSL, ``pip install drone-models``) keeps each drone as a section of a TOML
file that its models read through ``drone_models.core.load_params``; simulators built on it
fly whatever that section describes. This module writes the section its ``first_principles``
model reads: the rigid body, the thrust and drag-torque curves in RPM, the mixing matrix, and
the body-frame linear drag matrix, the one place where the format holds a discovered effect.

Conventions, checked against drone-models 0.1.0: commands and rotor speeds in RPM, thrust
``f_i = c_0 + c_1 rpm + c_2 rpm^2`` in N, rotors numbered as :mod:`nanosysid.dynamics` numbers
them (its mixing matrix rows are ``ROTOR_Y``, ``-ROTOR_X`` and ``-SPIN``), drag force
``R D R^T v`` with ``D`` in N per m/s of body velocity.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

from nanosysid.dynamics import ROTOR_X, ROTOR_Y, SPIN
from nanosysid.vehicle import Vehicle

__all__ = ["RAD_PER_RPM", "DRAG", "parameters", "toml_text"]

RAD_PER_RPM = 2.0 * math.pi / 60.0

# How a library entry enters the format's one place for an effect, the diagonal of the body-frame
# linear drag matrix (N per m/s), from its coefficients and the vehicle, and how the file's header
# says it is held. induced_drag grows with the rotor speeds' sum, which the format's constant
# matrix cannot follow: it is taken at hover, where the four rotors carry the weight.
DRAG: dict[str, tuple[Callable[[Sequence[float], Vehicle], tuple[float, float, float]], str]] = {
    "linear_drag": (lambda c, vh: (-c[0], -c[0], -c[1]), "linear_drag"),
    "induced_drag": (lambda c, vh: tuple(-4.0 * vh.hover_speed * k for k in (c[0], c[0], c[1])),
                     "induced_drag (at hover)"),
}


def parameters(vehicle: Vehicle, effects: Mapping[str, Sequence[float]], delay: float = 0.0
               ) -> tuple[dict[str, Any], list[str], list[str]]:
    """The ``first_principles`` section of a vehicle and its named effects.

    Args:
        vehicle: The identified vehicle (k_F in N s^2/rad^2, k_M in N m s^2/rad^2).
        effects: Named effects' coefficients, as the discovered model records them.
        delay: The rotor speeds' delay (s) the model applies (``input_delay``), which the format
            cannot hold.

    Returns:
        The section's fields (plain floats and lists), the names of the effects it holds and
        of those the format cannot hold (left out).
    """
    drag = [0.0, 0.0, 0.0]
    held = [name for name in effects if name in DRAG]
    left = [name for name in effects if name not in DRAG] + (["input_delay"] if delay > 0 else [])
    for name in held:
        drag = [d + e for d, e in zip(drag, DRAG[name][0](list(effects[name]), vehicle))]
    inertia = [float(j) for j in vehicle.inertia]
    params = {
        "gravity_vec": [0.0, 0.0, -float(vehicle.gravity)],
        "mass": float(vehicle.mass),
        "L": float(vehicle.arm),
        "J": [[inertia[i] if i == k else 0.0 for k in range(3)] for i in range(3)],
        "rpm2thrust": [0.0, 0.0, float(vehicle.k_f) * RAD_PER_RPM**2],
        "rpm2torque": [0.0, 0.0, float(vehicle.k_m) * RAD_PER_RPM**2],
        "thrust2torque": float(vehicle.k_m) / float(vehicle.k_f),
        "mixing_matrix": [list(ROTOR_Y), [-x for x in ROTOR_X], [-s for s in SPIN]],
        "drag_matrix": [[drag[i] if i == k else 0.0 for k in range(3)] for i in range(3)],
        # the identified models read the measured rotor speeds: no rotor inertia, no rotor dynamics
        "prop_inertia": 0.0,
        "rotor_dyn_coef": [0.0, 0.0, 0.0, 0.0],
    }
    return params, held, left


def _value(v: Any) -> str:
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return repr(float(v))


def toml_text(name: str, params: Mapping[str, Any], *, held: Sequence[str], left: Sequence[str], source: str) -> str:
    """The section as TOML text, headed by what it holds and what it leaves out.

    Args:
        name: The section's name, the ``drone_model`` drone-models is asked for.
        params: :func:`parameters`' fields.
        held: Effects in its drag matrix.
        left: Effects the format cannot hold.
        source: What the parameters were identified from, for the header.
    """
    lines = [
        f"# The Crazyflie 2.1 Brushless as identified by nanosysid from {source}, for drone-models'",
        "# first_principles model (append this section to drone_models/data/params.toml, and an empty",
        f"# [{name}] to drone_models/first_principles/params.toml). Commands are the rotor speeds in RPM;",
        "# call the dynamics with rotor_vel=None: the rotor speeds are the model's input, their dynamics",
        "# were not identified (rotor_dyn_coef zero).",
    ]
    lines.append("# Effects in drag_matrix: " + (", ".join(DRAG[h][1] for h in held) if held else "none") + ".")
    lines.append("# Effects the format cannot hold, left out: " + (", ".join(left) if left else "none") + ".")
    lines.append(f"[{name}]")
    lines += [f"{k} = {_value(v)}" for k, v in params.items()]
    return "\n".join(lines) + "\n"
