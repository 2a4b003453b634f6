"""Straight-line C99 from scalar arithmetic, with an exact count of the operations it emits.

The physics step is written once, in scalar form, over :class:`Sym` values: run on a
:class:`Tracer` it emits one ``const float`` per operation and counts each kind. Constants
fold in Python (``x * 1``, ``x + 0`` and ``0 * x`` emit nothing), so the count is that of
the code the microcontroller runs.
"""

from __future__ import annotations

import re
from collections import Counter
from typing import Sequence, Union

from nanosysid import effects as library
from nanosysid.dynamics import ROTOR_X, ROTOR_Y, SPIN, integrate, signed_sum
from nanosysid.vehicle import Vehicle

__all__ = ["Tracer", "Sym", "Vector", "flit", "sqrt", "physics_step_c", "physics_step_scalar", "Num"]


def flit(x: float) -> str:
    """A C float literal that reads back to the same float32."""
    return f"{float(x):.9e}f"


class Tracer:
    """Collects C statements, one operation each (``add``, ``mul``, ``div``, ``sqrt``, ...)."""

    def __init__(self) -> None:
        self.ops: list[tuple[str, str, str]] = []  # (name, expression, kind)

    def input(self, ref: str) -> "Sym":
        return Sym(self, ref)

    def emit(self, expr: str, kind: str) -> "Sym":
        name = f"t{len(self.ops)}"
        self.ops.append((name, expr, kind))
        return Sym(self, name)

    def live(self, outputs: Sequence["Num"]) -> tuple[list[str], Counter]:
        """The statements the outputs need, in order, and the count of their operations;
        what no output uses (the position of the RK4 stages, say) is left out."""
        need = {o.ref for o in outputs if isinstance(o, Sym)}
        keep = []
        for name, expr, kind in reversed(self.ops):
            if name in need:
                keep.append((name, expr, kind))
                need.update(re.findall(r"\bt\d+\b", expr))
        keep.reverse()
        return [f"const float {n} = {e};" for n, e, _ in keep], Counter(k for _, _, k in keep)


class Sym:
    """A float32 value in generated C; arithmetic with Python numbers folds identities."""

    __slots__ = ("t", "ref")

    def __init__(self, tracer: Tracer, ref: str) -> None:
        self.t, self.ref = tracer, ref

    @staticmethod
    def _r(x: "Num") -> str:
        return x.ref if isinstance(x, Sym) else flit(x)

    def _bin(self, other: "Num", op: str, kind: str, swap: bool = False) -> "Num":
        if not isinstance(other, Sym):
            other = float(other)
            if op == "*" and other == 1.0:
                return self
            if op == "*" and other == 0.0:
                return 0.0
            if op in "+-" and other == 0.0:
                return self if (op == "+" or not swap) else -self
        a, b = (self._r(other), self.ref) if swap else (self.ref, self._r(other))
        return self.t.emit(f"{a} {op} {b}", kind)

    def __add__(self, o): return self._bin(o, "+", "add")
    def __radd__(self, o): return self._bin(o, "+", "add", swap=True)
    def __sub__(self, o): return self._bin(o, "-", "add")
    def __rsub__(self, o): return self._bin(o, "-", "add", swap=True)
    def __mul__(self, o): return self._bin(o, "*", "mul")
    def __rmul__(self, o): return self._bin(o, "*", "mul", swap=True)
    def __truediv__(self, o): return self._bin(o, "/", "div")
    def __rtruediv__(self, o): return self._bin(o, "/", "div", swap=True)
    def __neg__(self): return self.t.emit(f"-{self.ref}", "neg")
    def __abs__(self): return self.t.emit(f"fabsf({self.ref})", "abs")


Num = Union[Sym, float]


def sqrt(x: Num) -> Num:
    if isinstance(x, Sym):
        return x.t.emit(f"sqrtf({x.ref})", "sqrt")
    return float(x) ** 0.5


def _cross(a: Sequence[Num], b: Sequence[Num]) -> list[Num]:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _rotate(qv: Sequence[Num], qw: Num, v: Sequence[Num]) -> list[Num]:
    """:func:`nanosysid.so3.quat_rotate`: ``v + w t + q_v x t`` with ``t = 2 q_v x v``."""
    t = [2.0 * c for c in _cross(qv, v)]
    ct = _cross(qv, t)
    return [v[i] + qw * t[i] + ct[i] for i in range(3)]


class Vector(list):
    """A state of scalars with the vector arithmetic :func:`nanosysid.dynamics.rk4_step` uses."""

    def __add__(self, other):  # type: ignore[override]
        return Vector(a + b for a, b in zip(self, other))

    def __rmul__(self, c: float) -> "Vector":
        return Vector(c * a for a in self)

    __mul__ = __rmul__


def _normalise(x: Sequence[Num]) -> list[Num]:
    """:func:`nanosysid.dynamics.renormalise` in scalar form."""
    q = x[6:10]
    inv = 1.0 / sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [*x[:6], *(qi * inv for qi in q), *x[10:]]


def _dynamics(x: Sequence[Num], om: Sequence[Num], s: Sequence[Num], om_dot: Sequence[Num], *, mass, inertia, k_f,
              k_m, arm, gravity, angular_dynamics, effects=()) -> Vector:
    """``dx/dt`` of :func:`nanosysid.dynamics.quad_dynamics` in scalar form: rotor speeds
    ``om``, their squares ``s`` (computed once per step, not per RK4 stage) and rates
    ``om_dot``; ``effects`` adds the named effects' wrench (``(name, theta)`` pairs of
    :mod:`nanosysid.effects`)."""
    v, qv, qw, w = x[3:6], x[6:9], x[9], x[10:13]
    thrust = k_f * (s[0] + s[1] + s[2] + s[3])
    f_b = [0.0, 0.0, thrust]
    tau_extra = [0.0, 0.0, 0.0]
    if effects:
        vehicle = Vehicle(mass=mass, inertia=tuple(inertia), arm=arm, k_f=k_f, k_m=k_m, gravity=gravity)
        sg = library.Signals(v=_rotate([-c for c in qv], qw, v), w=w, om=om, s=s, om_dot=om_dot, z=x[2])
        for name, theta in effects:
            f, t = library.wrench(name, theta, sg, vehicle)
            f_b = [a + b for a, b in zip(f_b, f)]
            tau_extra = [a + b for a, b in zip(tau_extra, t)]
    rot = _rotate(qv, qw, f_b)
    v_dot = [rot[i] * (1.0 / mass) + g for i, g in enumerate((0.0, 0.0, -gravity))]
    cw = _cross(qv, w)
    q_dot = [0.5 * (qw * w[i] + cw[i]) for i in range(3)]
    q_dot.append(-0.5 * (qv[0] * w[0] + qv[1] * w[1] + qv[2] * w[2]))
    axes = angular_axes(angular_dynamics)
    if any(axes):
        kl = k_f * arm
        tau = [kl * signed_sum(ROTOR_Y, s), kl * signed_sum([-c for c in ROTOR_X], s),
               k_m * signed_sum([-c for c in SPIN], s)]
        tau = [a + b for a, b in zip(tau, tau_extra)]
        Jw = [inertia[i] * w[i] for i in range(3)]
        c = _cross(w, Jw)
        w_dot = [(tau[i] - c[i]) * (1.0 / inertia[i]) if axes[i] else 0.0 for i in range(3)]
    else:
        w_dot = [0.0, 0.0, 0.0]
    return Vector([*v, *v_dot, *q_dot, *w_dot])


def physics_step_scalar(y: Sequence[Num], u: Sequence[Num], *, dt: float, substeps: int, **params) -> list[Num]:
    """:class:`nanosysid.models.physics.PhysicsStep` in scalar form, through the same
    :func:`nanosysid.dynamics.integrate`. With ``effects``, ``u`` holds the rotor speeds and
    their rates (8 values), as :class:`nanosysid.discover.model.AugmentedStep`."""
    om, om_dot = list(u[:4]), list(u[4:8])
    s = [ui * ui for ui in om]

    def f(x, _):
        return _dynamics(x, om, s, om_dot, **params)

    return integrate(f, Vector(y), u, dt=dt, substeps=substeps, normalise=_normalise)


def angular_axes(angular_dynamics: bool | Sequence[bool]) -> tuple[bool, ...]:
    """The body axes (x, y, z) whose torque equation a step integrates: one flag for all three
    (:class:`~nanosysid.models.physics.PhysicsStep`), or one per axis
    (:class:`~nanosysid.discover.model.AugmentedStep`; ``dw_i/dt = 0`` about the others)."""
    if isinstance(angular_dynamics, (bool, int)):
        return (bool(angular_dynamics),) * 3
    return tuple(bool(a) for a in angular_dynamics)


def torque_equation_words(angular_dynamics) -> str:
    """Where a step integrates the torque equation, in words."""
    axes = angular_axes(angular_dynamics)
    if all(axes) or not any(axes):
        return f"{'with' if any(axes) else 'without'} the torque equation"
    on = [a for a, keep in zip("xyz", axes) if keep]
    return f"with the torque equation about body {', '.join(on)} only (dw/dt = 0 about the other axes)"


def physics_step_c(name: str, *, dt: float, substeps: int, **params) -> tuple[str, Counter]:
    """C source of ``void <name>(const float y[13], const float u[NU], float y_next[13])`` and
    the count of each operation it performs (``NU`` is 8 with effects: rotor speeds and rates)."""
    tr = Tracer()
    nu = 8 if params.get("effects") else 4
    y = [tr.input(f"y[{i}]") for i in range(13)]
    u = [tr.input(f"u[{i}]") for i in range(nu)]
    out = physics_step_scalar(y, u, dt=dt, substeps=substeps, **params)
    lines, counts = tr.live(out)
    body = [f"    {line}" for line in lines]
    body += [f"    y_next[{i}] = {Sym._r(o)};" for i, o in enumerate(out)]
    effects = "".join(f" + {n}" for n, _ in params.get("effects", ()))
    src = (f"/* RK4 of the rigid-body dynamics{effects}, {substeps} substep(s) of {dt / substeps:g} s, "
           f"{torque_equation_words(params['angular_dynamics'])}: "
           f"{sum(counts.values())} floating-point operations. */\n"
           f"void {name}(const float y[13], const float u[{nu}], float y_next[13])\n{{\n" + "\n".join(body) + "\n}\n")
    return src, counts
