"""The networks of the learned models, injected into :class:`nanosysid.models.learned.SequenceModel`.

Every network maps the normalised features of one step, ``x (B, 16)`` (the 12-dimensional
output and the 4 rotor speeds), and its recurrent state to the normalised increment
``(B, 12)`` and the next state::

    state = net.init_state(y0)        # y0 (B, 12), normalised; None for feed-forward networks
    d, state = net(x, state)

A network is a module of this package that names its class ``NETWORK``; its key is the
module's name (``mlp``, ``lstm``), which a model's config (``network.name``) and its
checkpoint use. A new network is one new file here: nothing to register. A checkpoint
names its network by that key with its constructor's arguments, so loading one imports
only modules of this package and never runs code from the file.
"""

from __future__ import annotations

import importlib
import re

from torch import nn

__all__ = ["network_class", "network_name"]


def network_class(name: str) -> type[nn.Module]:
    """The ``NETWORK`` class of the module ``name`` of this package."""
    if not re.fullmatch(r"[a-z][a-z0-9_]*", str(name)):
        raise KeyError(f"network name {name!r}: expected the name of a module of {__name__}")
    try:
        module = importlib.import_module(f"{__name__}.{name}")
    except ModuleNotFoundError:
        raise KeyError(f"unknown network {name!r}: no module {__name__}.{name}") from None
    cls = getattr(module, "NETWORK", None)
    if cls is None:
        raise KeyError(f"{__name__}.{name} defines no NETWORK class")
    return cls


def network_name(net: nn.Module) -> str:
    """The key of a network: the name of the module that defines its class."""
    module = type(net).__module__
    if not module.startswith(f"{__name__}."):
        raise KeyError(f"{type(net).__name__} is not a network of {__name__}")
    return module.rsplit(".", 1)[1]
