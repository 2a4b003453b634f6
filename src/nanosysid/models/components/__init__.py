"""The networks of the learned models, injected into :class:`nanosysid.models.learned.SequenceModel`.

Every network maps the normalised features of one step, ``x (B, 16)`` (the 12-dimensional
output and the 4 rotor speeds), and its recurrent state to the normalised increment
``(B, 12)`` and the next state::

    state = net.init_state(y0)        # y0 (B, 12), normalised; None for feed-forward networks
    d, state = net(x, state)

A checkpoint names its network by the key of :data:`NETWORKS` with its constructor's
arguments, so loading one never runs code from the file.
"""

from __future__ import annotations

from torch import nn

from nanosysid.models.components.lstm import LSTMNet
from nanosysid.models.components.mlp import MLPNet

__all__ = ["NETWORKS", "network_name"]

NETWORKS: dict[str, type[nn.Module]] = {
    "mlp": MLPNet,
    "lstm": LSTMNet,
}


def network_name(net: nn.Module) -> str:
    """The key of a network's class in :data:`NETWORKS`."""
    for name, cls in NETWORKS.items():
        if type(net) is cls:
            return name
    raise KeyError(f"{type(net).__name__} is not a registered network; add it to NETWORKS")
