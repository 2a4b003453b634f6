"""Knowledge: named physical effects from the literature that the nominal model leaves out.

These are hypotheses, not the simulator's world (that is :mod:`nanosysid.sim.world`, which
this module never imports): discovery searches them, the augmented model adds the ones it
names, and the export writes them out in C. Each effect is written once, as the columns of
a linear model of the extra body wrench,

    ``[F_B; tau_B] = Phi(x, Omega, dOmega/dt) theta``,  ``Phi`` of shape ``(6, P)``,

over component scalars (:class:`Signals`). The same function gives the regression's feature
columns and the augmented model's batched torch wrench (:func:`features`, over tensors), and
the generated C (:func:`wrench`, over the C generator's traced scalars). ``input_delay`` is
the one nonlinear entry: a delay of the recorded rotor speeds, found by search.

Rotor layout and spin directions are :mod:`nanosysid.dynamics`'.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import torch
from torch import Tensor

from nanosysid import so3
from nanosysid.dynamics import ROTOR_X, ROTOR_Y, SPIN, signed_sum
from nanosysid.vehicle import Vehicle

__all__ = ["CHANNELS", "Signals", "Effect", "LIBRARY", "NOMINAL", "DELAY", "signals", "features", "wrench",
           "split_coefficients", "entry"]

CHANNELS = ("F_x", "F_y", "F_z", "tau_x", "tau_y", "tau_z")


@dataclass(frozen=True)
class Signals:
    """What an effect's columns are made of, component by component: each a float, a tensor
    ``(...,)`` or a traced scalar of the C generator.

    Attributes:
        v: Air velocity in the body frame (still air): ``R^T v`` (m/s), 3 components.
        w: Body rates (rad/s), 3.
        om: Rotor speeds (rad/s), 4; ``s`` their squares; ``om_dot`` their rates (rad/s^2).
    """

    v: Sequence[Any]
    w: Sequence[Any]
    om: Sequence[Any]
    s: Sequence[Any]
    om_dot: Sequence[Any]


Columns = Callable[[Signals, Vehicle], list[list[Any]]]


@dataclass(frozen=True)
class Effect:
    """One named effect of the library.

    Attributes:
        name: The effect's name.
        description: What it is, physically, with its source.
        params: Names of its coefficients, with units.
        columns: ``(Signals, vehicle) -> 6 rows of P entries`` (0.0 where a channel is untouched);
            None for the nonlinear ``input_delay``.
        touches: The benchmark quantities it acts on directly.
    """

    name: str
    description: str
    params: tuple[str, ...]
    columns: Columns | None
    touches: tuple[str, ...]


def _zero_rows(P: int) -> list[list[Any]]:
    return [[0.0] * P for _ in range(6)]


def _induced_drag(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    total = sg.om[0] + sg.om[1] + sg.om[2] + sg.om[3]
    rows = _zero_rows(2)
    rows[0][0] = -(total * sg.v[0])
    rows[1][0] = -(total * sg.v[1])
    rows[2][1] = -(total * sg.v[2])
    return rows


def _quadratic_drag(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    rows = _zero_rows(2)
    rows[0][0] = -(abs(sg.v[0]) * sg.v[0])
    rows[1][0] = -(abs(sg.v[1]) * sg.v[1])
    rows[2][1] = -(abs(sg.v[2]) * sg.v[2])
    return rows


def _cg_offset(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    thrust = vehicle.k_f * (sg.s[0] + sg.s[1] + sg.s[2] + sg.s[3])
    rows = _zero_rows(2)
    # torque of the thrust (0, 0, T) about a centre of mass at (r_x, r_y, 0): T (-r_y, r_x, 0)
    rows[4][0] = thrust
    rows[3][1] = -thrust
    return rows


def _rotor_spread(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    # rotor i with k_F (1 + d_i) and k_M (1 + d_i) adds d_i times its own column of the mixer
    kl = vehicle.k_f * vehicle.arm
    rows = _zero_rows(4)
    for i in range(4):
        rows[2][i] = vehicle.k_f * sg.s[i]
        rows[3][i] = (kl * ROTOR_Y[i]) * sg.s[i]
        rows[4][i] = (-kl * ROTOR_X[i]) * sg.s[i]
        rows[5][i] = (-vehicle.k_m * SPIN[i]) * sg.s[i]
    return rows


def _rotor_gyro(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    h = signed_sum(SPIN, sg.om)  # rotor angular momentum along body z, per unit rotor inertia
    rows = _zero_rows(1)
    # gyroscopic torque -w x (0, 0, J_r h) and the reaction to spinning the rotors up
    rows[3][0] = -(sg.w[1] * h)
    rows[4][0] = sg.w[0] * h
    rows[5][0] = -signed_sum(SPIN, sg.om_dot)
    return rows


def _nominal(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    """Corrections of the nominal coefficients: k_F (thrust and roll/pitch torque) and k_M."""
    L = vehicle.arm
    rows = _zero_rows(2)
    rows[2][0] = sg.s[0] + sg.s[1] + sg.s[2] + sg.s[3]
    rows[3][0] = L * signed_sum(ROTOR_Y, sg.s)
    rows[4][0] = L * signed_sum([-x for x in ROTOR_X], sg.s)
    rows[5][1] = signed_sum([-s for s in SPIN], sg.s)
    return rows


NOMINAL = Effect("nominal", "the quadratic rotor model's own coefficients, refitted alongside",
                 ("dk_F [N s²/rad²]", "dk_M [N m s²/rad²]"), _nominal, ("p", "v", "R", "w"))

DELAY = Effect("input_delay", "the recorded rotor speeds lag the true ones by a delay (telemetry over a radio link)",
               ("delay [s]",), None, ("p", "v", "R", "w"))

LIBRARY: dict[str, Effect] = {e.name: e for e in (
    Effect("induced_drag", "blade flapping and induced drag, linear in the rotor speeds and the body velocity: "
           "F_B = -(Σ Ω_i) diag(K_xy, K_xy, K_z) v_B (Förster's Crazyflie 2 identification)",
           ("K_xy [kg/rad]", "K_z [kg/rad]"), _induced_drag, ("p", "v")),
    Effect("quadratic_drag", "quadratic airframe drag: F_B = -diag(c_xy, c_xy, c_z) |v_B| v_B",
           ("c_xy [kg/m]", "c_z [kg/m]"), _quadratic_drag, ("p", "v")),
    DELAY,
    Effect("cg_offset", "centre of gravity at (r_x, r_y) off the rotors' centre: the thrust torques roll and pitch, "
           "tau = T (-r_y, r_x, 0)", ("r_x [m]", "r_y [m]"), _cg_offset, ("R", "w")),
    Effect("rotor_spread", "rotors of unequal coefficients k_F (1 + d_i), k_M (1 + d_i) (manufacturing spread, wear)",
           ("d_1 [-]", "d_2 [-]", "d_3 [-]", "d_4 [-]"), _rotor_spread, ("p", "v", "R", "w")),
    Effect("rotor_gyro", "rotor inertia J_r: gyroscopic torque -ω × (0, 0, J_r Σ s_i Ω_i) and yaw reaction "
           "-J_r Σ s_i dΩ_i/dt", ("J_r [kg m²]",), _rotor_gyro, ("R", "w")),
)}


def entry(name: str) -> Effect:
    """The library entry (or :data:`NOMINAL`) called ``name``."""
    if name == NOMINAL.name:
        return NOMINAL
    try:
        return LIBRARY[name]
    except KeyError:
        raise KeyError(f"no effect {name!r} in the library; known: {', '.join(LIBRARY)}") from None


def signals(x: Tensor, om: Tensor, om_dot: Tensor) -> Signals:
    """The components of batched state ``(..., 13)``, rotor speeds and rates ``(..., 4)``."""
    v_b = so3.quat_rotate(so3.quat_conj(x[..., 6:10]), x[..., 3:6])
    return Signals(v=v_b.unbind(-1), w=x[..., 10:13].unbind(-1), om=om.unbind(-1), s=(om * om).unbind(-1),
                   om_dot=om_dot.unbind(-1))


def features(names: Sequence[str], x: Tensor, om: Tensor, om_dot: Tensor, vehicle: Vehicle) -> Tensor:
    """The columns of the named effects side by side, ``(..., 6, sum P)``: the regression's
    features, and with coefficients ``theta`` the augmented model's wrench ``features @ theta``."""
    sg = signals(x, om, om_dot)
    zero = torch.zeros(x.shape[:-1], dtype=x.dtype, device=x.device)
    rows: list[list[Tensor]] = [[] for _ in range(6)]
    for name in names:
        for c, row in enumerate(entry(name).columns(sg, vehicle)):
            rows[c] += [e if isinstance(e, Tensor) else zero + e for e in row]
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def wrench(name: str, theta: Sequence[float], sg: Signals, vehicle: Vehicle) -> tuple[list[Any], list[Any]]:
    """Body force and torque (3 entries each) of one effect with coefficients ``theta``,
    over component scalars: what the generated C computes."""
    out = []
    for row in entry(name).columns(sg, vehicle):
        total: Any = 0.0
        for col, th in zip(row, theta):
            if isinstance(col, float) and col == 0.0:
                continue
            total = col * float(th) if isinstance(total, float) and total == 0.0 else total + col * float(th)
        out.append(total)
    return out[:3], out[3:]


def split_coefficients(names: Sequence[str], theta: Sequence[float]) -> dict[str, list[float]]:
    """A coefficient vector laid out as :func:`features` lays out its columns, per effect."""
    out, k = {}, 0
    for name in names:
        n = len(entry(name).params)
        out[name] = [float(t) for t in theta[k:k + n]]
        k += n
    if k != len(theta):
        raise ValueError(f"{len(theta)} coefficients for effects {list(names)}, which take {k}")
    return out
