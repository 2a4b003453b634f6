"""What one prediction step of a model costs: trainable parameters and floating-point operations."""

from __future__ import annotations

from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode

__all__ = ["step_cost", "physics_flops"]


def physics_flops(step) -> int:
    """Exact operation count of a :class:`~nanosysid.models.physics.PhysicsStep`, from its
    generated C (:mod:`nanosysid.export.cgen`)."""
    from nanosysid.export.csource import physics_source

    return physics_source("physics", step.vehicle, dt=step.dt, substeps=step.substeps,
                          angular_dynamics=step.angular_dynamics).flops


def _torch_flops(fn, *args) -> int:
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        fn(*args)
    return int(counter.get_total_flops())


def _learned_cost(model) -> dict[str, Any]:
    from nanosysid.export.csource import TILDE_FLOPS
    from nanosysid.models.learned import from_tilde, to_tilde

    params = sum(p.numel() for p in model.parameters() if p.requires_grad)
    y = torch.zeros(1, 13, dtype=model.y_mean.dtype)
    y[:, 9] = 1.0  # identity attitude
    yt = to_tilde(y)  # (1, 12)
    u = model.u_mean.unsqueeze(0)  # (1, 4)
    with torch.no_grad():
        state = model.init_state(yt)  # the LSTM's initialisation runs once per rollout, not per step
    flops = _torch_flops(model.step, yt, u, state)
    method = "torch.utils.flop_counter (matrix products, 2 per multiply-add)"
    if model.arch == "phys_res":
        # torch counts only the physics step's matrix product; the exact count replaces it
        flops += (physics_flops(model.physics) - _torch_flops(model.physics, from_tilde(yt), u)
                  + TILDE_FLOPS["to_tilde"] + TILDE_FLOPS["from_tilde"])
        method += " for the network; exact count of the generated C for the physics step"
    return {"params": int(params), "flops": int(flops), "flops_method": method}


def step_cost(predict: Any) -> dict[str, Any]:
    """Parameters and FLOPs of one step of a benchmark predictor.

    Learned models: trainable parameters, and the FLOPs of one recurrent step as torch's
    FLOP counter reports them (matrix products only, a multiply-add counted as 2). The
    physics models: no trainable parameters (``params: None``) and the exact operation count
    of their generated C step. ``flops: None`` means no count is available for that model
    (the naive model computes nothing; the oracle is the simulator).
    """
    from nanosysid.models.learned import LearnedPredictor
    from nanosysid.models.physics import PhysicsStep
    from nanosysid.rollout import StepPredictor

    if isinstance(predict, LearnedPredictor):
        return _learned_cost(predict.model)
    if isinstance(predict, StepPredictor) and isinstance(predict.step, PhysicsStep):
        return {"params": None, "flops": physics_flops(predict.step), "flops_method": "exact count of the generated C"}
    from nanosysid.discover.model import AugmentedPredictor

    if isinstance(predict, AugmentedPredictor):
        from nanosysid.export.steps import exportable

        return {"params": None, "flops": exportable(predict, "discovered").c.flops,
                "flops_method": "exact count of the generated C"}
    return {"params": None, "flops": None, "flops_method": None}
