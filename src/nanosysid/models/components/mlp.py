"""Feed-forward network of the residual models: one step's increment from its features."""

from __future__ import annotations

from typing import Any

from torch import Tensor, nn

__all__ = ["MLP", "MLPNet"]


class MLP(nn.Sequential):
    """Fully connected network with tanh activations between layers."""

    def __init__(self, n_in: int, hidden: list[int], n_out: int) -> None:
        layers: list[nn.Module] = []
        for h in hidden:
            layers += [nn.Linear(n_in, h), nn.Tanh()]
            n_in = h
        layers.append(nn.Linear(n_in, n_out))
        super().__init__(*layers)

    @property
    def linears(self) -> list[nn.Linear]:
        return [m for m in self if isinstance(m, nn.Linear)]


class MLPNet(nn.Module):
    """``d = MLP(x)``, no recurrent state.

    Args:
        hidden: Hidden layer sizes.
        zero_init: Start with the last layer at zero, so the untrained model adds nothing to
            its base (physics + residual starts as the physics model).
        n_in, n_out: Feature and increment sizes.
    """

    recurrent = False

    def __init__(self, hidden: list[int] = (120, 120), *, zero_init: bool = False, n_in: int = 16,
                 n_out: int = 12) -> None:
        super().__init__()
        self.mlp = MLP(n_in, list(hidden), n_out)
        if zero_init:
            nn.init.zeros_(self.mlp[-1].weight)
            nn.init.zeros_(self.mlp[-1].bias)

    def init_state(self, y0: Tensor) -> Any:
        return None

    def forward(self, x: Tensor, state: Any = None) -> tuple[Tensor, Any]:
        return self.mlp(x), None

NETWORK = MLPNet
