"""Physical parameters of the benchmark vehicle, the Crazyflie 2.1 Brushless."""

from __future__ import annotations

from dataclasses import asdict, fields
from typing import Any, Mapping

from nanosysid.settings import configured

__all__ = ["Vehicle"]


@configured("vehicle/cf21bl.yaml")
class Vehicle:
    """Rigid-body and rotor parameters; defaults are the benchmark's vehicle as
    ``conf/vehicle/cf21bl.yaml`` gives it (values and sources there).

    Attributes:
        mass: Total mass (kg), battery and decks included.
        inertia: Diagonal of the body-frame inertia matrix (kg m^2), from Crazyflow.
        arm: Effective lever arm L (m): 50 mm centre-to-motor times cos(45 deg).
        k_f: Thrust coefficient (N s^2/rad^2).
        k_m: Moment coefficient (N m s^2/rad^2).
        gravity: Gravitational acceleration (m/s^2).
    """

    mass: float
    inertia: tuple[float, float, float]
    arm: float
    k_f: float
    k_m: float
    gravity: float

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> "Vehicle":
        """Build from a config mapping; unknown keys are an error, missing keys take defaults."""
        names = {f.name for f in fields(cls)}
        unknown = set(cfg) - names
        if unknown:
            raise KeyError(f"vehicle config: unknown keys {sorted(unknown)}; expected {sorted(names)}")
        kw = dict(cfg)
        if "inertia" in kw:
            kw["inertia"] = tuple(float(v) for v in kw["inertia"])
        return cls(**kw)

    def dynamics_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`nanosysid.dynamics.quad_dynamics`."""
        return asdict(self)

    @property
    def hover_speed(self) -> float:
        """Rotor speed (rad/s) at which the four rotors together carry the weight."""
        return (self.mass * self.gravity / (4 * self.k_f)) ** 0.5
