"""The nominal model augmented with named effects: ``physics+<effects>``, a benchmark predictor."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from nanosysid import dynamics
from nanosysid import effects as library
from nanosysid.dataio import atomic_file, json_text, read_json_record
from nanosysid.errors import DataError
from nanosysid.rollout import advance_inputs, as_tensor, rollout
from nanosysid.vehicle import Vehicle

__all__ = ["AXES", "AugmentedStep", "AugmentedPredictor", "augmented_inputs", "rotor_rates", "save_discovered",
           "load_discovered", "integrating", "integrated_names", "integrated_flags"]


AXES = ("x", "y", "z")  # the body axes, as model.json names the ones whose torque is integrated


class AugmentedStep(nn.Module):
    """RK4 of the rigid-body dynamics with an extra body wrench ``Phi(x, Omega, dOmega/dt) theta``
    from the named effects, the torque equation integrated about the body axes marked in
    ``integrated`` (x, y, z) and the angular velocity held (``dw_i/dt = 0``, the paper's physics
    model) about the others: the torque effects act only about integrated axes.

    The step's input is ``(B, 8)`` (rotor speeds and their rate), then, where an effect reads
    the rotor speeds' history (:attr:`history`), their squares' low-passes ``(B, 4 K)``
    (:func:`nanosysid.effects.slow_squares`), then optionally a further measured wrench
    ``[F_B; tau_B]`` added as it is (used to ask what a channel's measured disagreement would do
    to the rollouts).
    """

    def __init__(self, vehicle: Vehicle, effects: Sequence[str] = (), theta: Sequence[float] = (), *,
                 dt: float = 0.01, substeps: int = 1, integrated: Sequence[bool] = (True, True, True)) -> None:
        super().__init__()
        self.vehicle, self.effects, self.dt, self.substeps = vehicle, tuple(effects), dt, substeps
        self.integrated = tuple(bool(a) for a in integrated)
        if len(self.integrated) != len(AXES):
            raise ValueError(f"integrated: one flag per body axis (3), got {len(self.integrated)}")
        self.register_buffer("theta", torch.tensor(list(theta), dtype=torch.float64))
        # 1 where the state's derivative is kept, 0 on the angular velocity of a held axis
        keep = torch.ones(13, dtype=torch.float64)
        keep[10:13] = torch.tensor([float(a) for a in self.integrated], dtype=torch.float64)
        self.register_buffer("keep", keep, persistent=False)
        self._f = functools.partial(dynamics.quad_dynamics, **vehicle.dynamics_kwargs(),
                                    angular_dynamics=any(self.integrated))
        self.history = any("history" in library.entry(n).needs for n in self.effects)
        self.width = 8 + (4 * len(library.SLOW_TIMES) if self.history else 0)

    def _dx(self, x: Tensor, u_ext: Tensor) -> Tensor:
        om, om_dot = u_ext[..., :4], u_ext[..., 4:8]
        slow = u_ext[..., 8:self.width] if self.history else None
        force = torque = None
        if self.effects:
            w = library.features(self.effects, x, om, om_dot, self.vehicle, s_slow=slow) @ self.theta.to(x.dtype)
            force, torque = w[..., :3], w[..., 3:]
        if u_ext.shape[-1] > self.width:
            e = u_ext[..., self.width:self.width + 6]
            force = e[..., :3] if force is None else force + e[..., :3]
            torque = e[..., 3:] if torque is None else torque + e[..., 3:]
        dx = self._f(x, om, force_body=force, torque_body=torque)
        return dx if all(self.integrated) or not any(self.integrated) else dx * self.keep.to(dx.dtype)

    def forward(self, y: Tensor, u_ext: Tensor) -> Tensor:
        return dynamics.integrate(self._dx, y, u_ext, dt=self.dt, substeps=self.substeps)

    def coefficients(self) -> dict[str, list[float]]:
        """The coefficients of each effect, by name."""
        return library.split_coefficients(self.effects, self.theta.tolist())


def rotor_rates(u: Tensor, dt: float) -> Tensor:
    """``dOmega/dt`` along the horizon of ``u (B, H, 4)``: central differences, one-sided at the ends."""
    if u.shape[1] < 2:
        return torch.zeros_like(u)
    d = torch.empty_like(u)
    d[:, 1:-1] = (u[:, 2:] - u[:, :-2]) / (2 * dt)
    d[:, 0] = (u[:, 1] - u[:, 0]) / dt
    d[:, -1] = (u[:, -1] - u[:, -2]) / dt
    return d


def augmented_inputs(u: Tensor, delay: float, dt: float, history: bool = False) -> Tensor:
    """The augmented step's input along ``u (B, H, 4)``: the rotor speeds read ``delay`` (s)
    later and their rates, ``(B, H, 8)``; with ``history`` also their squares' low-passes
    ``(B, H, 8 + 4 K)``, started at rest at the window's first rotor speeds (a window carries no
    earlier history)."""
    om = advance_inputs(u, delay / dt)
    parts = [om, rotor_rates(om, dt)]
    if history:
        parts.append(library.slow_squares(om, dt))
    return torch.cat(parts, dim=-1)


class AugmentedPredictor:
    """``predict(y0 (B, 13), u (B, H, 4)) -> (B, H, 13)`` of an :class:`AugmentedStep`, with the
    recorded rotor speeds advanced by ``delay`` (s) when a telemetry delay was found."""

    def __init__(self, step: AugmentedStep, *, delay: float = 0.0, name: str = "discovered") -> None:
        self.step, self.delay, self.name = step, float(delay), name

    @torch.no_grad()
    def __call__(self, y0, u, extra=None) -> np.ndarray:
        y = as_tensor(y0, torch.float64)
        parts = [augmented_inputs(as_tensor(u, torch.float64), self.delay, self.step.dt, self.step.history)]
        if extra is not None:
            parts.append(as_tensor(extra, torch.float64))
        return rollout(self.step, y, torch.cat(parts, dim=-1)).numpy()

    def __repr__(self) -> str:
        return (f"AugmentedPredictor({'+'.join(('physics',) + self.step.effects)}, delay={self.delay:g}, "
                f"torque integrated about {integrated_names(self.step.integrated) or 'no axis'})")


def integrating(predict: AugmentedPredictor, integrated: Sequence[bool] = (True, True, True)) -> AugmentedPredictor:
    """The same model with the torque equation integrated about the axes marked in ``integrated``."""
    p = predict.step
    step = AugmentedStep(p.vehicle, p.effects, p.theta.tolist(), dt=p.dt, substeps=p.substeps, integrated=integrated)
    return AugmentedPredictor(step, delay=predict.delay, name=predict.name)


def integrated_names(integrated: Sequence[bool]) -> str:
    """The axes whose torque is integrated, as model.json writes them (``"xy"``; ``""``: none)."""
    return "".join(a for a, on in zip(AXES, integrated) if on)


def integrated_flags(names: str) -> tuple[bool, bool, bool]:
    """:func:`integrated_names` read back."""
    return tuple(a in names for a in AXES)  # type: ignore[return-value]


def save_discovered(path: Path, vehicle: Vehicle, effects: Mapping[str, Mapping[str, Any]], delay: float,
                    dt: float = 0.01, substeps: int = 1, integrated: Sequence[bool] = (True, True, True)
                    ) -> dict[str, Any]:
    """The augmented model as JSON: vehicle (with the refitted k_F, k_M), effects and their
    coefficients, delay, and the body axes whose torque equation it integrates
    (``"integrated": "xyz"``; the angular velocity is held about the others)."""
    payload = {"format": "nanosysid-discovered-1", "vehicle": dataclasses.asdict(vehicle),
               "effects": {k: dict(v) for k, v in effects.items()}, "delay": float(delay), "dt": dt,
               "substeps": substeps, "integrated": integrated_names(integrated)}
    with atomic_file(Path(path)) as tmp:
        tmp.write_text(json_text(payload))
    return payload


def load_discovered(path: str | Path, *, name: str = "discovered") -> AugmentedPredictor:
    """The predictor of a model written by :func:`save_discovered`."""
    d = read_json_record(path, "nanosysid-discovered-1", "a discovered model", "discover")
    vehicle = Vehicle.from_mapping(d["vehicle"])
    names = list(d["effects"])
    for n in names:
        try:
            e = library.entry(n)
        except KeyError as err:
            raise DataError(f"{path}: {err.args[0]}; rerun the discover stage") from None
        if e.kind != "wrench":
            raise DataError(f"{path}: {n!r} is a {e.kind}, not an extra wrench: it belongs in the vehicle or the delay")
        if len(d["effects"][n]["coefficients"]) != e.n_columns:
            raise DataError(f"{path}: effect {n!r} has {len(d['effects'][n]['coefficients'])} coefficients, "
                            f"expected {e.n_columns}")
    axes = d.get("integrated", "xyz")  # absent: the torque equation integrated about every axis
    if not isinstance(axes, str) or set(axes) - set(AXES):
        raise DataError(f"{path}: 'integrated' is {axes!r}; it must name body axes among x, y, z (\"xz\", \"\")")
    theta = [c for n in names for c in d["effects"][n]["coefficients"]]
    step = AugmentedStep(vehicle, names, theta, dt=float(d["dt"]), substeps=int(d["substeps"]),
                         integrated=integrated_flags(axes))
    return AugmentedPredictor(step, delay=float(d["delay"]), name=name)
