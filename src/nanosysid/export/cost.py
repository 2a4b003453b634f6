"""What one prediction step of a model costs: trainable parameters and floating-point operations."""

from __future__ import annotations

from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode

from nanosysid.export.csource import TILDE_FLOPS, physics_source
from nanosysid.export.steps import augmented_step
from nanosysid.models.learned import from_tilde, to_tilde

__all__ = ["physics_flops", "no_cost", "physics_cost", "learned_cost", "augmented_cost"]


def physics_flops(step) -> int:
    """Exact operation count of a :class:`~nanosysid.models.physics.PhysicsStep`, from its
    generated C (:mod:`nanosysid.export.cgen`)."""
    return physics_source("physics", step.vehicle, dt=step.dt, substeps=step.substeps,
                          angular_dynamics=step.angular_dynamics).flops


def _torch_flops(fn, *args) -> int:
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        fn(*args)
    return int(counter.get_total_flops())


def learned_cost(predict) -> dict[str, Any]:
    """Trainable parameters, and the FLOPs of one recurrent step as torch's FLOP counter
    reports them (matrix products only, a multiply-add counted as 2)."""
    model = predict.model

    params = sum(p.numel() for p in model.parameters() if p.requires_grad)
    y = torch.zeros(1, 13, dtype=model.y_mean.dtype)
    y[:, 9] = 1.0  # identity attitude
    yt = to_tilde(y)  # (1, 12)
    u = model.u_mean.unsqueeze(0)  # (1, 4)
    with torch.no_grad():
        state = model.init_state(yt)  # the LSTM's initialisation runs once per rollout, not per step
    flops = _torch_flops(model.step, yt, u, state)
    method = "torch.utils.flop_counter (matrix products, 2 per multiply-add)"
    if model.physics is not None:
        # torch counts only the physics step's matrix product; the exact count replaces it
        flops += (physics_flops(model.physics) - _torch_flops(model.physics, from_tilde(yt), u)
                  + TILDE_FLOPS["to_tilde"] + TILDE_FLOPS["from_tilde"])
        method += " for the network; exact count of the generated C for the physics step"
    return {"params": int(params), "flops": int(flops), "flops_method": method}


def no_cost(predict) -> dict[str, Any]:
    """No count: the naive model computes nothing, the oracle is the simulator."""
    return {"params": None, "flops": None, "flops_method": None}


def physics_cost(predict) -> dict[str, Any]:
    """No trainable parameters; the exact operation count of the generated C step."""
    return {"params": None, "flops": physics_flops(predict.step), "flops_method": "exact count of the generated C"}


def augmented_cost(predict) -> dict[str, Any]:
    """The discovered model: as :func:`physics_cost`, with its effects in the C step (no count
    where an effect reads the rotor speeds' history, which the C step is not given)."""
    if predict.step.history:
        return {"params": None, "flops": None, "flops_method": "none: an effect reads the rotor speeds' history"}
    return {"params": None, "flops": augmented_step(predict, "discovered").c.flops,
            "flops_method": "exact count of the generated C"}
