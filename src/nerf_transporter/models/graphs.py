"""CUDA graphs for a network's training passes: one launch for its forward, one for its backward.

At batch 1 a training step launches thousands of small kernels and a GPU waits on those launches,
not on arithmetic (docs/measurements.md, "Speed on one GPU"). `graph_training_passes(net)` makes
the network capture its forward and backward passes (`torch.cuda.make_graphed_callables`) the first
time it trains on CUDA, and replay them from then on, for that input's shape. Every other call runs
the network as before: inference (no grad, or eval mode), the CPU, autocast, another input shape, and a
second call before the first one's backward (a replay would overwrite the first call's saved
activations). The replays compute what the eager passes compute (tests/models/test_graphs.py,
which needs CUDA).

The captured passes take channels-last input, and `to_channels_last(net, optimizers)` moves the
parameters (and the optimizer state kept for them) to that memory layout too: cuDNN then runs the
convolutions without layout conversions (measured on an H100: a width-64 mira step 29 -> 22 ms;
eagerly, where a step waits on launches, channels-last is slower, 37 -> 44 ms). Same values, same
`state_dict`. `ungraph_training_passes(net)` restores the network's own `forward`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import torch
from torch import nn

_EAGER_FORWARD = "_eager_forward"  # the network's own forward, while graphed


class _Passes(nn.Module):
    """The network as make_graphed_callables takes it: a module owning its parameters, calling its
    own forward (not the graphed one installed on it)."""

    def __init__(self, net: nn.Module, forward: Callable[[torch.Tensor], torch.Tensor]) -> None:
        super().__init__()
        self.net = net
        self.eager_forward = forward

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.eager_forward(x)


def _signature(x: torch.Tensor) -> tuple:
    return tuple(x.shape), x.dtype, x.device, x.requires_grad


def graph_training_passes(net: nn.Module) -> None:
    """Make `net` (one tensor in, one tensor out) run its CUDA training passes as graphs."""
    if hasattr(net, _EAGER_FORWARD):
        return
    eager_forward = net.forward
    captured: dict[str, object] = {}
    state = {"awaiting_backward": False}

    def backward_started(grad: torch.Tensor) -> None:
        state["awaiting_backward"] = False

    def forward(x: torch.Tensor) -> torch.Tensor:
        if (
            not (net.training and torch.is_grad_enabled() and x.is_cuda)
            or torch.is_autocast_enabled()
            or state["awaiting_backward"]
        ):
            return eager_forward(x)
        if not captured:
            sample = x.detach().clone(memory_format=torch.channels_last)
            sample.requires_grad_(x.requires_grad)
            passes = torch.cuda.make_graphed_callables(_Passes(net, eager_forward), (sample,))
            captured.update(signature=_signature(x), passes=passes)
        if captured["signature"] != _signature(x):
            return eager_forward(x)
        y = captured["passes"](x)
        if y.requires_grad:
            state["awaiting_backward"] = True
            y.register_hook(backward_started)
        return y

    setattr(net, _EAGER_FORWARD, eager_forward)
    net.forward = forward


def ungraph_training_passes(net: nn.Module) -> None:
    """Undo `graph_training_passes` (the captured graphs are freed with the last reference)."""
    if hasattr(net, _EAGER_FORWARD):
        del net.forward
        delattr(net, _EAGER_FORWARD)


def to_channels_last(net: nn.Module, optimizers: Iterable[torch.optim.Optimizer] = ()) -> None:
    """Move the 4-D parameters of `net`, and the optimizers' state of the same shape (Adam's
    moments, e.g. restored from a checkpoint), to channels-last memory. Both or neither: fused
    and multi-tensor optimizers read a parameter and its state in memory order, so a parameter
    whose layout differs from its state's is silently updated with another element's moments."""
    net.to(memory_format=torch.channels_last)
    for optimizer in optimizers:
        for parameter in net.parameters():
            state = optimizer.state.get(parameter, {})
            for key, value in state.items():
                if torch.is_tensor(value) and value.dim() == 4 and value.shape == parameter.shape:
                    state[key] = value.contiguous(memory_format=torch.channels_last)


def is_graphed(net: nn.Module) -> bool:
    return hasattr(net, _EAGER_FORWARD)
