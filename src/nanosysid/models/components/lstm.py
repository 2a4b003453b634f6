"""Recurrent network of the paper's LSTM model: an MLP gives the initial state from ``ỹ_0``."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from nanosysid.models.components.mlp import MLP

__all__ = ["LSTMNet"]


class LSTMNet(nn.Module):
    """LSTM cell over the step's features, linear readout of the increment.

    Args:
        hidden: Hidden size of the LSTM.
        init_hidden: Hidden layer of the MLP that maps the normalised ``ỹ_0`` to the initial
            hidden and cell states.
        n_in, n_out: Feature and increment sizes; the initial state is computed from the
            first ``n_out`` features (the output).
    """

    recurrent = True

    def __init__(self, hidden: int = 64, init_hidden: int = 32, *, n_in: int = 16, n_out: int = 12) -> None:
        super().__init__()
        self.init = MLP(n_out, [init_hidden], 2 * hidden)
        self.cell = nn.LSTMCell(n_in, hidden)
        self.readout = nn.Linear(hidden, n_out)

    def init_state(self, y0: Tensor) -> tuple[Tensor, Tensor]:
        h, c = self.init(y0).chunk(2, dim=-1)
        return torch.tanh(h), c

    def forward(self, x: Tensor, state: tuple[Tensor, Tensor]) -> tuple[Tensor, tuple[Tensor, Tensor]]:
        h, c = self.cell(x, state)
        return self.readout(h), (h, c)

NETWORK = LSTMNet
