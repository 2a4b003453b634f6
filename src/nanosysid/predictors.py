"""The predictors of the benchmark by kind: one registry maps each kind to its builder, its
exporter and its cost counter. It sits above everything it registers (the models, the
simulator's oracle, discovery's augmented model, the exporters), none of which imports it.

A model's config block (``models.<name>``) names its ``kind``; the rest are the builder's
keyword arguments. Learned models of every network are one kind (``learned``): their network
comes from the checkpoint.

Example::

    from nanosysid import predictors
    predict = predictors.predictor("physics")   # "naive", "physics_full", "oracle", or "models/lstm/model.pt"
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable

from nanosysid.discover.model import load_discovered
from nanosysid.dataio import check_step
from nanosysid.errors import ConfigError, ExportError
from nanosysid.export import cost as costs
from nanosysid.export import steps
from nanosysid.identify import identified_vehicle
from nanosysid.models.learned import LearnedPredictor, load_checkpoint
from nanosysid.models.physics import PhysicsStep, naive_predict
from nanosysid.rollout import StepPredictor
from nanosysid.vehicle import Vehicle

log = logging.getLogger("nanosysid.predictors")

__all__ = ["ModelKind", "KINDS", "predictor", "build_from_options", "step_cost", "exportable"]

Predictor = Callable[..., Any]


@dataclass(frozen=True)
class ModelKind:
    """What the pipeline does with one kind of model.

    Attributes:
        build: ``build(**options) -> predictor``.
        export: ``export(predictor, name) -> Exportable`` (:mod:`nanosysid.export.steps`);
            None when the kind has no step to run on the microcontroller.
        cost: ``cost(predictor) -> {"params", "flops", "flops_method"}`` of one step.
    """

    build: Callable[..., Predictor]
    export: Callable[[Predictor, str], Any] | None
    cost: Callable[[Predictor], dict[str, Any]]


def _vehicle(v: Any) -> Vehicle:
    """A vehicle from a config mapping; the paper's (``Vehicle()``, equal to ``conf/vehicle``)
    for the Python API's ``predictors.predictor("physics")``."""
    if v is None:
        return Vehicle()
    return v if isinstance(v, Vehicle) else Vehicle.from_mapping(v)


def _check_step(name: str, dt: Any, substeps: Any) -> None:
    """A model steps once per sample of the benchmark's data (``dt`` its period); ``substeps``
    integrate finer within it."""
    check_step(dt, f"{name}: dt")
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ConfigError(f"{name}: substeps = {substeps!r}, expected a positive whole number")


def _naive(**options: Any) -> Predictor:
    if options:
        raise ConfigError(f"naive model takes no options, got {sorted(options)}")
    return naive_predict


def _physics(*, angular_dynamics: bool, name: str) -> Callable[..., Predictor]:
    def build(*, vehicle: Any = None, dt: float = 0.01, substeps: int = 1, identified: str | None = None) -> Predictor:
        _check_step(name, dt, substeps)
        v = identified_vehicle(_vehicle(vehicle), identified)
        if identified is None:
            # a user's row differs from the pipeline's here (identified_vehicle logs the file otherwise)
            log.info("%s: k_F %.4g, k_M %.4g, the vehicle's own, not identified (give identified=<the identify "
                     "stage's params.json>)", name, v.k_f, v.k_m)
        step = PhysicsStep(v, dt=dt, substeps=substeps, angular_dynamics=angular_dynamics)
        return StepPredictor(step, name=name)

    return build


def _oracle(*, effects: Any = None, vehicle: Any = None, substeps: int = 4, dt: float = 0.01,
            rotor_delay: float | None = None, seed: int = 0, compile: bool = True) -> Predictor:
    from nanosysid import sim  # the simulator (scipy's filters and splines) only for the oracle

    return sim.oracle_of(effects=effects, vehicle=vehicle, substeps=substeps, dt=dt, rotor_delay=rotor_delay,
                         seed=seed, compile=compile)


def _learned(*, checkpoint: str, **training: Any) -> Predictor:
    """A trained model from its checkpoint; the network and training keys of its config are
    in the checkpoint (or only matter to training), so they are not needed here."""
    model, ckpt = load_checkpoint(checkpoint)
    # a checkpoint of another model (an LSTM's where a residual MLP is configured) is refused
    net = ckpt["network"]["name"]
    wanted = (training.get("network") or {}).get("name")
    if wanted is not None and wanted != net:
        raise ConfigError(f"{checkpoint}: holds a {net} network, but the model's config names {wanted}")
    if "network" in training and ("physics" in training) != (ckpt["physics"] is not None):
        said = ("has a physics base, but the model's config has no physics key" if ckpt["physics"] is not None
                else "has no physics base, but the model's config gives one")
        raise ConfigError(f"{checkpoint}: the network {said}")
    return LearnedPredictor(model, name=net)


def _discovered(*, model: str) -> Predictor:
    """The nominal model with the effects the discover stage named (``model.json``)."""
    return load_discovered(model)


def _external(**options: Any) -> Predictor:
    """A predictor of the user's own, built by Hydra's instantiation of the block: ``_target_``
    names a callable (``package.module.name``, importable from the project's root) called with
    the block's other keys, which returns ``predict(y0 (B, 13), u (B, H, 4)) -> (B, H, 13)``
    (numpy or torch): a fitted least-squares model, an ARX, a GP, another package's model;
    ``_partial_: true`` makes the callable itself the predictor."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    target = options.get("_target_")
    if not isinstance(target, str) or not target:
        raise ConfigError("a model of kind 'external' names its builder with _target_ (package.module.name), "
                          f"got {target!r}")
    try:
        predict = instantiate(options)
    except InstantiationException as e:
        first = str(e).strip().splitlines()[0]
        raise ConfigError(f"model {target}: cannot build it: {first}") from None
    if not callable(predict):
        raise ConfigError(f"model {target}: returned {type(predict).__name__}, not a predict(y0, u)")
    return predict


KINDS: dict[str, ModelKind] = {
    "naive": ModelKind(_naive, None, costs.no_cost),
    "physics": ModelKind(_physics(angular_dynamics=False, name="physics"), steps.physics_step, costs.physics_cost),
    "physics_full": ModelKind(_physics(angular_dynamics=True, name="physics_full"), steps.physics_step,
                              costs.physics_cost),
    "oracle": ModelKind(_oracle, None, costs.no_cost),
    "learned": ModelKind(_learned, steps.learned_step, costs.learned_cost),
    "discovered": ModelKind(_discovered, steps.augmented_step, costs.augmented_cost),
    "external": ModelKind(_external, None, costs.no_cost),
}


def _kind(kind: str) -> ModelKind:
    try:
        return KINDS[kind]
    except KeyError:
        raise ConfigError(f"unknown model kind {kind!r}; known: {', '.join(sorted(KINDS))}") from None


def predictor(kind: str, **options: Any) -> Predictor:
    """A predictor ``predict(y0 (B,13), u (B,H,4)) -> (B,H,13)`` by kind: ``naive``,
    ``physics``, ``physics_full``, ``oracle`` (simulated data), ``discovered``, or the path of a
    learned model's checkpoint (``models/<name>/model.pt``).

    Options are the model's config keys (for the physics models: ``vehicle``, a mapping or
    :class:`~nanosysid.vehicle.Vehicle`; ``dt``; ``substeps``; ``identified``, the path of an
    ``identify`` result whose k_F and k_M replace the vehicle's). Without ``identified`` a physics
    model has the vehicle's own k_F and k_M, not the ones the pipeline's rows use
    (``models/physics/params.json``); it logs which it has.
    """
    if str(kind).endswith((".pt", ".ckpt")):
        return _learned(checkpoint=kind)
    return _kind(kind).build(**options)


def build_from_options(options: dict[str, Any]) -> Predictor:
    """The predictor of a ``models.<name>`` block as plain data (``kind`` plus options).

    ``artifact`` names the file or folder the model is made from and ``code`` its own code, for
    DVC's dependency tracking, and ``train`` only matters to training; none is an option of the
    predictor. A block of kind ``external`` names its builder with ``_target_`` (:func:`_external`).
    A learned model's ``network`` and ``physics`` are checked against its checkpoint.
    """
    opts = {k: v for k, v in options.items() if k not in ("kind", "artifact", "code", "train")}
    if "kind" not in options:
        raise ConfigError(f"a model's config names its kind (one of {', '.join(sorted(KINDS))}), got the keys "
                          f"{sorted(options)}")
    return predictor(options["kind"], **opts)


def step_cost(kind: str, predict: Predictor) -> dict[str, Any]:
    """Parameters and FLOPs of one step of a predictor of this kind."""
    return _kind(kind).cost(predict)


def exportable(kind: str, predict: Predictor, name: str) -> Any:
    """The exportable step (:class:`nanosysid.export.steps.Exportable`) of a predictor."""
    export = _kind(kind).export
    if export is None:
        raise ExportError(f"model {name!r} (kind {kind!r}) has no step to export: "
                          f"kinds with one are {', '.join(k for k, m in KINDS.items() if m.export)}")
    return export(predict, name)
