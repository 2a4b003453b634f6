"""Benchmark models by name."""

from __future__ import annotations

from typing import Any, Callable

from nanosysid.vehicle import Vehicle

__all__ = ["build_predictor", "build_from_config", "identified_vehicle", "MODEL_KINDS"]


def _vehicle(v: Any) -> Vehicle:
    if v is None:
        return Vehicle()
    return v if isinstance(v, Vehicle) else Vehicle.from_mapping(v)


def _naive(**options: Any) -> Callable:
    from nanosysid.models.physics import naive_predict

    if options:
        raise TypeError(f"naive model takes no options, got {sorted(options)}")
    return naive_predict


def identified_vehicle(vehicle: Any = None, identified: str | None = None) -> Vehicle:
    """The vehicle with k_F and k_M from an ``identify`` result (``params.json``), if given."""
    v = _vehicle(vehicle)
    if identified:
        import dataclasses
        import json
        from pathlib import Path

        fit = json.loads(Path(identified).read_text())
        v = dataclasses.replace(v, k_f=float(fit["k_f"]), k_m=float(fit["k_m"]))
    return v


def _physics(*, angular_dynamics: bool, name: str) -> Callable:
    def build(*, vehicle: Any = None, dt: float = 0.01, substeps: int = 1, identified: str | None = None) -> Callable:
        from nanosysid.models.physics import PhysicsStep
        from nanosysid.rollout import StepPredictor

        v = identified_vehicle(vehicle, identified)
        step = PhysicsStep(v, dt=dt, substeps=substeps, angular_dynamics=angular_dynamics)
        return StepPredictor(step, name=name)

    return build


def _oracle(*, effects: Any = None, vehicle: Any = None, substeps: int = 4, dt: float = 0.01,
            rotor_delay: float | None = None) -> Callable:
    from nanosysid import sim

    eff = None if effects is None else dict(effects)
    return sim.oracle(eff, vehicle=_vehicle(vehicle), substeps=substeps, dt=dt, rotor_delay=rotor_delay)


def _learned(*, checkpoint: str, **architecture: Any) -> Callable:
    """A trained model from its checkpoint; the architecture keys of its config are in the
    checkpoint too, so they are not needed here."""
    from nanosysid.models.learned import LearnedPredictor, load_model

    model, ckpt = load_model(checkpoint)
    return LearnedPredictor(model, name=ckpt["hparams"]["arch"])


def _discovered(*, model: str) -> Callable:
    """The nominal model with the effects the discover stage named (``model.json``)."""
    from nanosysid.discover.model import load_model

    return load_model(model)


MODEL_KINDS: dict[str, Callable[..., Callable]] = {
    "naive": _naive,
    "physics": _physics(angular_dynamics=False, name="physics"),
    "physics_full": _physics(angular_dynamics=True, name="physics_full"),
    "oracle": _oracle,
    "learned": _learned,
    "discovered": _discovered,
}


def build_predictor(name: str, **options: Any) -> Callable:
    """Build a predictor ``predict(y0 (B,13), u (B,H,4)) -> (B,H,13)`` by model name, or from
    the path of a learned model's checkpoint."""
    if name.endswith((".pt", ".ckpt")):
        return _learned(checkpoint=name)
    try:
        factory = MODEL_KINDS[name]
    except KeyError:
        raise KeyError(f"unknown model {name!r}; known: {', '.join(sorted(MODEL_KINDS))}") from None
    return factory(**options)


def build_from_config(options: dict[str, Any]) -> Callable:
    """Build the predictor of a ``models.<name>`` config block (``kind`` plus options).

    ``artifact`` names the file or folder the model is made from, for DVC's dependency
    tracking; it is not an option of the model.
    """
    opts = {k: v for k, v in options.items() if k not in ("kind", "artifact")}
    return build_predictor(options["kind"], **opts)
