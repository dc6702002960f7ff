"""The one MLP building block of every learned network: linear layers with SiLU between them.

:class:`MLP` is a single network (``members=None``, layers are ``nn.Linear``) or an
ensemble of ``members`` independent networks evaluated as one batched program (layers
are :class:`EnsembleLinear`). Every parameter is float32. The weights are initialised
by one of the schemes below, drawn from a ``torch.Generator`` the caller seeds; the
arrays of the linear layers are written and read by :mod:`dynoplan.models.mlp_file`.

Users: the dynamics ensemble (:class:`~dynoplan.models.neural_dynamics.GaussianEnsembleMLP`),
the goal network (:mod:`dynoplan.models.goal_network`), the gear grasp recogniser and
the gear insertion network.
"""

import math
from collections.abc import Callable, Sequence
from itertools import pairwise
from typing import cast

import torch
from torch import nn
from torch.nn import functional as F

Init = Callable[[torch.Tensor, torch.Tensor, int, torch.Generator], None]
"""``init(weight, bias, fan_in, generator)`` fills one layer's parameters in place."""


def truncated_normal_init(weight: torch.Tensor, bias: torch.Tensor, fan_in: int,
                          generator: torch.Generator) -> None:
    """mbrl-lib's: weights from a normal with std ``1 / (2 sqrt(fan_in))`` truncated at
    two standard deviations, biases zero."""
    std = 1.0 / (2.0 * math.sqrt(fan_in))
    nn.init.trunc_normal_(weight, std=std, a=-2 * std, b=2 * std, generator=generator)
    bias.zero_()


def uniform_init(weight: torch.Tensor, bias: torch.Tensor, fan_in: int,
                 generator: torch.Generator) -> None:
    """PyTorch's ``nn.Linear`` default: weights, then biases, uniform in
    ``+-1 / sqrt(fan_in)``."""
    bound = 1.0 / math.sqrt(fan_in)
    weight.uniform_(-bound, bound, generator=generator)
    bias.uniform_(-bound, bound, generator=generator)


def uniform_weight_init(weight: torch.Tensor, bias: torch.Tensor, fan_in: int,
                        generator: torch.Generator) -> None:
    """Weights uniform in ``+-1 / sqrt(fan_in)``, biases zero."""
    bound = 1.0 / math.sqrt(fan_in)
    weight.uniform_(-bound, bound, generator=generator)
    bias.zero_()


class EnsembleLinear(nn.Module):
    """``members`` independent linear layers ``fan_in -> fan_out`` as one batched product.

    ``forward`` maps ``(members, batch, fan_in)`` to ``(members, batch, fan_out)``;
    member ``k`` only sees ``x[k]``. Weight ``(members, fan_in, fan_out)``, bias
    ``(members, 1, fan_out)``.

    With ``fused_bias`` the bias is accumulated inside the product (``torch.baddbmm``),
    else added after it (``x @ weight + bias``, which also broadcasts an input of
    ``(1, batch, fan_in)`` to every member). The two round differently; each network
    keeps the one it was trained with.
    """

    def __init__(self, members: int, fan_in: int, fan_out: int, fused_bias: bool) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(members, fan_in, fan_out))
        self.bias = nn.Parameter(torch.empty(members, 1, fan_out))
        self.fused_bias = fused_bias

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.fused_bias:
            return torch.baddbmm(self.bias, x, self.weight)
        return x @ self.weight + self.bias


_Linear = nn.Linear | EnsembleLinear


class MLP(nn.Module):
    """Linear layers ``sizes[0] -> sizes[1] -> ... -> sizes[-1]`` with SiLU between them.

    Args:
        sizes: input width, hidden widths, output width.
        init: fills each layer's weight and bias, layer by layer, from ``generator``.
        generator: the only random source of the initialisation.
        members: ``None`` for one network, whose ``forward`` maps ``(batch, sizes[0])``
            to ``(batch, sizes[-1])`` (layers are ``nn.Linear``, weight ``(out, in)``;
            constructing one also draws PyTorch's default initialisation from the
            global torch random state, which ``init`` then overwrites); else the size of
            an ensemble evaluated as one program, ``(members, batch, sizes[0])`` ->
            ``(members, batch, sizes[-1])`` (layers are :class:`EnsembleLinear`).
        fused_bias: for an ensemble, see :class:`EnsembleLinear`.
    """

    def __init__(self, sizes: Sequence[int], init: Init, generator: torch.Generator,
                 members: int | None = None, fused_bias: bool = True) -> None:
        super().__init__()
        self.sizes = tuple(int(s) for s in sizes)
        self.linears = nn.ModuleList(
            nn.Linear(fan_in, fan_out) if members is None
            else EnsembleLinear(members, fan_in, fan_out, fused_bias)
            for fan_in, fan_out in pairwise(self.sizes))
        with torch.no_grad():
            for weight, bias, fan_in in zip(self.weights, self.biases, self.sizes[:-1],
                                            strict=True):
                init(weight, bias, fan_in, generator)

    @property
    def weights(self) -> list[torch.Tensor]:
        """Every layer's weight parameter, first layer first."""
        return [cast(_Linear, layer).weight for layer in self.linears]

    @property
    def biases(self) -> list[torch.Tensor]:
        """Every layer's bias parameter, first layer first."""
        return [cast(_Linear, layer).bias for layer in self.linears]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x
        last = len(self.linears) - 1
        for i, layer in enumerate(self.linears):
            h = layer(h)
            if i < last:
                h = F.silu(h)
        return h


__all__ = ["MLP", "EnsembleLinear", "Init", "truncated_normal_init", "uniform_init",
           "uniform_weight_init"]
