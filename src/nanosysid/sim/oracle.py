"""The oracle: a predictor that integrates the simulator's true dynamics, hidden effects included.

It is the physical limit of the benchmark on simulated data. It knows every effect of the world,
the time-varying ones too: it is a *timed* predictor (:func:`nanosysid.protocol.evaluate` gives
it each window's start time and the flight's name), and replays the flight's turbulence and rotor thrust fluctuations from
the simulation's seed and the user-supplied wrench at the right times. What it still cannot
know is the measurement noise on ``y0`` and on ``u``, the rotor speeds between samples (it
interpolates linearly), and, with ``telemetry_delay``, the last rotor speeds of a window, which
the delay pushes past its end (it holds the last known one).
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from nanosysid import dynamics
from nanosysid.dataio import parse_flight_name
from nanosysid.errors import PredictionError
from nanosysid.numerics import LOOP_THREADS, threads
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
                 rotor_delay: float | None = None, seed: int = 0, extra_wrench: ExtraWrench | None = None) -> None:
        self.world = world
        # delay (s) of the rotor speeds in u behind the true ones: the telemetry_delay effect for
        # the simulator's direct output, 0 after the data pipeline has aligned the motor stream
        self.rotor_delay = world.telemetry_delay if rotor_delay is None else rotor_delay
        self.vehicle = vehicle or Vehicle()
        self.dt = dt
        self.substeps = substeps
        self.seed = seed
        self.extra_wrench = extra_wrench
        params = self.vehicle.dynamics_kwargs()
        params["inertia"] = world.inertia(self.vehicle)
        self._f = functools.partial(dynamics.quad_dynamics, **params)

    def _nature(self, flight: str | None, t_end: float) -> Nature:
        """The world's wrench on one flight: its realisation of the time-varying effects replayed
        from its name."""
        disturbance = None
        if self.world.timed:
            if flight is None:
                raise PredictionError("the oracle replays each flight's turbulence and thrust fluctuations: call it "
                                      "with flight=<its name> and t0 (protocol.evaluate does)")
            trajectory, run = parse_flight_name(flight)
            disturbance = self.world.disturbance(flight_key(self.seed, trajectory, run), t_end)
        return Nature([self.world], self.vehicle, disturbances=[disturbance], extra=self.extra_wrench)

    @torch.no_grad()
    @threads(LOOP_THREADS)
    def __call__(self, y0, u, t0=None, flight: str | None = None) -> np.ndarray:
        y = as_tensor(y0, torch.float64)
        om = advance_inputs(as_tensor(u, torch.float64), self.rotor_delay / self.dt)  # true speeds (B, H, 4)
        H = om.shape[1]
        t = None if t0 is None else as_tensor(t0, torch.float64).reshape(-1)
        nature = self._nature(flight, 1.0 if t is None else float(t.max()) + (H + 2) * self.dt)
        if nature.timed and t is None:
            raise PredictionError("the oracle's world depends on time (random effects or an extra wrench): call it with "
                                  "t0=<each window's start, s> (protocol.evaluate does)")
        # rotor speeds move linearly from one sample to the next; the last one is held
        om_next = torch.cat((om[:, 1:], om[:, -1:]), dim=1)
        om_dot = (om_next - om) / self.dt
        out = []
        for k in range(H):
            def f(x, w_rot, tk=None, od=om_dot[:, k]):
                force, torque = nature.wrench(tk, x, w_rot, od)
                return self._f(x, w_rot, force_body=force, torque_body=torque)

            def om_mid(j, h, k=k):
                return om[:, k] + om_dot[:, k] * (j + 0.5) * h

            y = dynamics.integrate(f, y, om_mid, dt=self.dt, substeps=self.substeps,
                                   t=None if t is None else t + k * self.dt)
            out.append(y)
        return torch.stack(out, dim=1).numpy()
