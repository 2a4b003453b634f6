"""The oracle: a predictor that integrates the simulator's true dynamics, hidden effects included.

It is the physical limit of the benchmark on simulated data. It knows every effect of the world,
the time-varying ones too: it is a *timed* predictor (:func:`nanosysid.protocol.evaluate` gives
it each window's start time and the flight's name), and replays the flight's turbulence and rotor thrust fluctuations from
the simulation's seed and the user-supplied wrench at the right times. What it still cannot
know is the measurement noise on ``y0`` and on ``u``, the rotor speeds between samples (it
interpolates linearly), and, with ``telemetry_delay``, the last rotor speeds of a window, which
the delay pushes past its end (it holds the last known one).

By default its derivative (the world's wrench and the rigid body) runs compiled, as the
simulator's step does (:func:`nanosysid.numerics.compiled`), wherever a call has half a block of
windows or more (:data:`BLOCK`; fewer would not pay for the compile): one graph for every world,
the windows in blocks of one size, a user's wrench added outside it. Inductor's code makes the
eager operations in their order, so the predictions have been the eager ones' bytes on every
world tried (``tests/test_sim.py``).

Held (``held=True``), it integrates the true dynamics with the angular velocity held
(``dw/dt = 0``), as the paper's physics model does: the limit of a model on that base, which
the true dynamics integrated are not (they drift with the turbulence's torque no model knows).
It then runs eagerly.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from nanosysid import dynamics
from nanosysid.dataio import parse_flight_name
from nanosysid.errors import PredictionError
from nanosysid.numerics import LOOP_THREADS, compiled, quiet_tracing, threads
from nanosysid.rollout import advance_inputs, as_tensor
from nanosysid.sim.simulator import flight_key
from nanosysid.sim.world import ExtraWrench, Nature, World
from nanosysid.vehicle import Vehicle

__all__ = ["Oracle"]


class Oracle:
    """``predict(y0 (B, 13), u (B, H, 4), t0=(B,), flight=name) -> (B, H, 13)`` with the true
    dynamics of ``world``; ``t0`` is each window's start in s from the flight's first sample."""

    timed = True

    def __init__(self, world: World, vehicle: Vehicle | None = None, *, dt: float = 0.01, substeps: int = 4,
                 rotor_delay: float | None = None, seed: int = 0, extra_wrench: ExtraWrench | None = None,
                 compile: bool = True, held: bool = False) -> None:
        self.world = world
        # delay (s) of the rotor speeds in u behind the true ones: the telemetry_delay effect for
        # the simulator's direct output, 0 after the data pipeline has aligned the motor stream
        self.rotor_delay = world.telemetry_delay if rotor_delay is None else rotor_delay
        self.vehicle = vehicle or Vehicle()
        self.dt = dt
        self.substeps = substeps
        self.seed = seed
        self.extra_wrench = extra_wrench
        self.compile = compile
        self.held = held
        params = self.vehicle.dynamics_kwargs()
        params["inertia"] = world.inertia(self.vehicle)
        self._f = functools.partial(dynamics.quad_dynamics, **params)
        if held:
            self._f = functools.partial(_held, self._f)

    def _disturbance(self, flight: str | None, t_end: float):
        """The world's realisation of its time-varying effects on one flight, replayed from the
        flight's name (None for a world without them)."""
        if not self.world.timed:
            return None
        if flight is None:
            raise PredictionError("the oracle replays each flight's turbulence and thrust fluctuations: call it "
                                  "with flight=<its name> and t0 (protocol.evaluate does)")
        trajectory, run = parse_flight_name(flight)
        return self.world.disturbance(flight_key(self.seed, trajectory, run), t_end)

    def _nature(self, disturbance, *, complete: bool = False) -> Nature:
        """The world's wrench on one flight (``complete``: every effect computed and the user's
        wrench left out, as the compiled derivative takes them)."""
        return Nature([self.world], self.vehicle, disturbances=[disturbance],
                      extra=None if complete else self.extra_wrench, complete=complete)

    @torch.no_grad()
    @threads(LOOP_THREADS)
    def __call__(self, y0, u, t0=None, flight: str | None = None) -> np.ndarray:
        y = as_tensor(y0, torch.float64)
        om = advance_inputs(as_tensor(u, torch.float64), self.rotor_delay / self.dt)  # true speeds (B, H, 4)
        if self.world.slow_share:
            # the speeds whose squares the rotors' wrench follows (the lag starts at the window)
            om = torch.from_numpy(np.sqrt(self.world.effective_squares(om.numpy() ** 2, self.dt)))
        H = om.shape[1]
        t = None if t0 is None else as_tensor(t0, torch.float64).reshape(-1)
        if (self.world.timed or self.extra_wrench is not None) and t is None:
            raise PredictionError("the oracle's world depends on time (random effects or an extra wrench): call it with "
                                  "t0=<each window's start, s> (protocol.evaluate does)")
        t_end = 1.0 if t is None else float(t.max()) + (H + 2) * self.dt
        # rotor speeds move linearly from one sample to the next; the last one is held
        om_next = torch.cat((om[:, 1:], om[:, -1:]), dim=1)
        om_dot = (om_next - om) / self.dt
        disturbance = self._disturbance(flight, t_end)
        if not (self.compile and not self.held and len(y) >= BLOCK // 2):
            return self._finite(self._rollout(self._nature(disturbance), y, om, om_dot, t).numpy())
        # blocks of BLOCK windows compiled (a last one of half a block or more padded to a block),
        # a shorter last one eagerly: one compiled shape, its compile paid where the work is large
        complete = self._nature(disturbance, complete=True)
        t = torch.zeros(len(y), dtype=torch.float64) if t is None else t
        return self._finite(torch.cat([self._compiled_rollout(complete, *b) if len(b[0]) >= BLOCK // 2
                                       else self._rollout(self._nature(disturbance), *b)
                                       for b in zip(*(a.split(BLOCK) for a in (y, om, om_dot, t)))]).numpy())

    def _finite(self, pred: np.ndarray) -> np.ndarray:
        """The rollouts, or an error naming the world whose true dynamics left the numbers."""
        bad = ~np.isfinite(pred)
        if bad.any():
            i, h, _ = np.argwhere(bad)[0]
            raise PredictionError(f"the oracle's world ({self.world}) predicts values that are not numbers from "
                                  f"window {i}, step {h + 1}: the vehicle cannot fly these strengths")
        return pred

    def _rollout(self, nature: Nature, y, om, om_dot, t):
        """The eager rollout ``(B, H, 13)`` from ``y (B, 13)`` under true rotor speeds ``om`` and
        their rates ``om_dot`` ``(B, H, 4)``, windows starting at ``t (B,)`` (s; None: untimed)."""
        def derivative(k):
            def f(x, w_rot, tk=None, od=om_dot[:, k]):
                force, torque = nature.wrench(tk, x, w_rot, od)
                return self._f(x, w_rot, force_body=force, torque_body=torque)
            return f

        return self._horizon(derivative, y, om, om_dot, t)

    def _horizon(self, derivative, y, om, om_dot, t, keep: int | None = None):
        """The states ``(B, H, 13)`` along the horizon, one step per sample, with the derivative
        ``derivative(k)`` of sample ``k`` and the rotor speeds moving linearly within it; the
        first ``keep`` windows (all if None)."""
        out = []
        for k in range(om.shape[1]):
            def om_mid(j, h, k=k):
                return om[:, k] + om_dot[:, k] * (j + 0.5) * h

            y = dynamics.integrate(derivative(k), y, om_mid, dt=self.dt, substeps=self.substeps,
                                   t=None if t is None else t + k * self.dt)
            out.append(y[:keep])
        return torch.stack(out, dim=1)

    def _compiled_rollout(self, nature: Nature, y, om, om_dot, t):
        """:meth:`_rollout` of ``BLOCK // 2`` to ``BLOCK`` windows through the compiled derivative
        (``nature`` complete), padded to a block with copies of the last window."""
        n = len(y)

        def padded(a):
            return torch.cat((a, a[-1:].expand(BLOCK - n, *a.shape[1:]))).contiguous() if n < BLOCK else a

        y, om, om_dot, t = (padded(a) for a in (y, om, om_dot, t))
        derivative = _compiled_derivative()
        base = functools.partial(dynamics.quad_dynamics, **{**self.vehicle.dynamics_kwargs(), "inertia": nature.inertia})
        extra = self.extra_wrench

        def at(k):
            def f(x, w_rot, tk, od=om_dot[:, k]):
                if extra is None:
                    push = torch.zeros_like(x[:, :6])
                else:  # (a user's wrench may be one for every window: broadcast as the eager sum does)
                    push = torch.cat([a.expand(len(x), 3) for a in extra(tk, x, w_rot, od)], -1)
                return derivative(x, w_rot, tk, od, push, nature=nature, base=base)
            return f

        with quiet_tracing():
            return self._horizon(at, y, om, om_dot, t, keep=n)


def _held(f, x, w_rot, **wrench):
    """``f``'s ``dx/dt (B, 13)`` with the angular velocity's derivative zero (``dw/dt = 0``)."""
    dx = f(x, w_rot, **wrench)
    return torch.cat((dx[..., :10], torch.zeros_like(dx[..., 10:])), -1)


# windows the compiled derivative takes at once: one shape, one compile, for flights of any
# length (a 20 s flight is one block)
BLOCK = 2048


def _derivative(x, w_rot, t, om_dot, push, *, nature: Nature, base):
    """``dx/dt`` of the true body: the world's wrench at times ``t (B,)`` plus ``push (B, 6)``
    (the user's force and torque, body frame), on the rigid body ``base``."""
    force, torque = nature.wrench(t, x, w_rot, om_dot)
    return base(x, w_rot, force_body=force + push[:, :3], torque_body=torque + push[:, 3:])


@functools.cache
def _compiled_derivative():
    return compiled(_derivative, setting="models.oracle.compile")
