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

__all__ = ["Tracer", "Sym", "flit", "sqrt", "physics_step_c", "physics_step_scalar", "Num"]


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


Num = Union[Sym, float]


def sqrt(x: Num) -> Num:
    if isinstance(x, Sym):
        return x.t.emit(f"sqrtf({x.ref})", "sqrt")
    return float(x) ** 0.5


def _cross(a: Sequence[Num], b: Sequence[Num]) -> list[Num]:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _dynamics(x: Sequence[Num], s: Sequence[Num], *, mass, inertia, k_f, k_m, arm, gravity, angular_dynamics):
    """``dx/dt`` of :func:`nanosysid.dynamics.quad_dynamics` in scalar form; ``s`` are the
    squared rotor speeds."""
    v, qv, qw, w = x[3:6], x[6:9], x[9], x[10:13]
    thrust = k_f * (s[0] + s[1] + s[2] + s[3])
    f_b = [0.0, 0.0, thrust]
    t = [2.0 * c for c in _cross(qv, f_b)]
    ct = _cross(qv, t)
    v_dot = [(f_b[i] + qw * t[i] + ct[i]) * (1.0 / mass) + g for i, g in enumerate((0.0, 0.0, -gravity))]
    cw = _cross(qv, w)
    q_dot = [0.5 * (qw * w[i] + cw[i]) for i in range(3)]
    q_dot.append(-0.5 * (qv[0] * w[0] + qv[1] * w[1] + qv[2] * w[2]))
    if angular_dynamics:
        kl = k_f * arm
        tau = [kl * (-s[0] - s[1] + s[2] + s[3]), kl * (-s[0] + s[1] + s[2] - s[3]),
               k_m * (-s[0] + s[1] - s[2] + s[3])]
        Jw = [inertia[i] * w[i] for i in range(3)]
        c = _cross(w, Jw)
        w_dot = [(tau[i] - c[i]) * (1.0 / inertia[i]) for i in range(3)]
    else:
        w_dot = [0.0, 0.0, 0.0]
    return [*v, *v_dot, *q_dot, *w_dot]


def physics_step_scalar(y: Sequence[Num], u: Sequence[Num], *, dt: float, substeps: int, **params) -> list[Num]:
    """:class:`nanosysid.models.physics.PhysicsStep` in scalar form: RK4 substeps with the
    input held, then the quaternion renormalised."""
    s = [ui * ui for ui in u]
    h = dt / substeps
    x = list(y)
    for _ in range(substeps):
        k1 = _dynamics(x, s, **params)
        k2 = _dynamics([a + (0.5 * h) * k for a, k in zip(x, k1)], s, **params)
        k3 = _dynamics([a + (0.5 * h) * k for a, k in zip(x, k2)], s, **params)
        k4 = _dynamics([a + h * k for a, k in zip(x, k3)], s, **params)
        x = [a + (h / 6.0) * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4)]
    q = x[6:10]
    inv = 1.0 / sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [*x[:6], *(qi * inv for qi in q), *x[10:]]


def physics_step_c(name: str, *, dt: float, substeps: int, **params) -> tuple[str, Counter]:
    """C source of ``void <name>(const float y[13], const float u[4], float y_next[13])`` and
    the count of each operation it performs."""
    tr = Tracer()
    y = [tr.input(f"y[{i}]") for i in range(13)]
    u = [tr.input(f"u[{i}]") for i in range(4)]
    out = physics_step_scalar(y, u, dt=dt, substeps=substeps, **params)
    lines, counts = tr.live(out)
    body = [f"    {line}" for line in lines]
    body += [f"    y_next[{i}] = {Sym._r(o)};" for i, o in enumerate(out)]
    src = (f"/* RK4 of the rigid-body dynamics, {substeps} substep(s) of {dt / substeps:g} s, "
           f"{'with' if params['angular_dynamics'] else 'without'} the torque equation: "
           f"{sum(counts.values())} floating-point operations. */\n"
           f"void {name}(const float y[13], const float u[4], float y_next[13])\n{{\n" + "\n".join(body) + "\n}\n")
    return src, counts
