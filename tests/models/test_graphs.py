"""`models.graphs`: CUDA graphs of the networks' training passes compute what the eager passes do,
and leave every other call (CPU, inference, other shapes) and the parameters alone."""

import copy
from types import SimpleNamespace

import pytest
import torch

from nerf_transporter.methods import METHODS
from nerf_transporter.models import ResNet43_8s
from nerf_transporter.models.graphs import (
    graph_training_passes,
    is_graphed,
    to_channels_last,
    ungraph_training_passes,
)

pytestmark = pytest.mark.usefixtures("one_thread")
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")


def test_graphed_net_on_the_cpu_trains_as_before_and_ungraphs():
    torch.manual_seed(0)
    net = ResNet43_8s(6, 3, width=4)
    x = torch.randn(2, 6, 16, 24)
    expected = net(x)
    expected.square().sum().backward()
    expected_grads = [p.grad.clone() for p in net.parameters()]
    keys = list(net.state_dict())
    net.zero_grad()
    graph_training_passes(net)
    assert is_graphed(net)
    y = net(x)
    y.square().sum().backward()
    assert torch.equal(y, expected)
    assert all(
        torch.equal(p.grad, e) for p, e in zip(net.parameters(), expected_grads, strict=True)
    )
    assert list(net.state_dict()) == keys
    ungraph_training_passes(net)
    assert not is_graphed(net) and "forward" not in vars(net)


def test_channels_last_parameters_keep_their_adam_moments():
    """A checkpoint's Adam moments (contiguous) follow the parameters to channels-last: the
    update is the one without the move (fused Adam would otherwise mix up elements)."""
    torch.manual_seed(0)
    nets = [ResNet43_8s(6, 3, width=4) for _ in range(2)]
    nets[1].load_state_dict(nets[0].state_dict())
    optimisers = [torch.optim.Adam(net.parameters(), lr=0.1, fused=True) for net in nets]
    gradients = [torch.randn_like(p) for p in nets[0].parameters()]
    for net, optimiser in zip(nets, optimisers, strict=True):
        for parameter, gradient in zip(net.parameters(), gradients, strict=True):
            parameter.grad = gradient.clone()
        optimiser.step()
    to_channels_last(nets[1], [optimisers[1]])
    assert nets[1].stem.weight.is_contiguous(memory_format=torch.channels_last)
    for net, optimiser in zip(nets, optimisers, strict=True):
        for parameter, gradient in zip(net.parameters(), gradients, strict=True):
            parameter.grad = torch.empty_like(parameter).copy_(gradient)  # the parameter's layout
        optimiser.step()
    for want, got in zip(nets[0].parameters(), nets[1].parameters(), strict=True):
        assert torch.allclose(got, want)


def test_cuda_graphs_option_leaves_a_cpu_model_eager_and_says_so():
    method = METHODS["mira"](width=4, cuda_graphs=True)
    with pytest.warns(UserWarning, match="trains on cpu, not CUDA"):
        method.on_train_start()
    assert method.networks() and not any(is_graphed(net) for net in method.networks())


@pytest.mark.parametrize(
    ("trainer", "refused"),
    [
        (dict(accumulate_grad_batches=2, world_size=1), "accumulate gradients"),
        (dict(accumulate_grad_batches=1, world_size=2), "for a fit on one GPU"),
    ],
)
def test_cuda_graphs_refuse_what_they_cannot_capture(trainer, refused, monkeypatch):
    method = METHODS["mira"](width=4, cuda_graphs=True)
    monkeypatch.setattr(method, "_device", torch.device("cuda", 0))  # no CUDA needed
    method._trainer = SimpleNamespace(precision="bf16-mixed", optimizers=[], **trainer)
    with (
        pytest.warns(UserWarning, match="bf16-mixed .autocast. the networks run eagerly"),
        pytest.raises(ValueError, match=refused),
    ):
        method.on_train_start()
    assert not any(is_graphed(net) for net in method.networks())


def _loss_and_gradients(method, batch: dict) -> tuple[float, torch.Tensor]:
    method.zero_grad()
    loss = method.losses(batch)["loss"]
    loss.backward()
    return float(loss), torch.cat([p.grad.flatten() for p in method.parameters()])


@needs_cuda
def test_graphed_training_follows_the_eager_one(monkeypatch):
    """Step by step, with new inputs and the parameters fused Adam has moved, the replayed passes
    give the eager passes' loss and gradients at the same parameters."""
    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", False)
    torch.manual_seed(0)
    graphed = METHODS["mira"](width=8, crop_size=16).cuda()
    eager = copy.deepcopy(graphed)
    for net in graphed.networks():  # as ImageMethod.on_train_start does
        to_channels_last(net)
        graph_training_passes(net)
    optimiser = graphed.configure_optimizers()
    generator = torch.Generator().manual_seed(1)
    for _ in range(3):
        batch = {
            "pick_image": torch.randn(1, 6, 40, 80, generator=generator),
            "place_images": torch.randn(1, 2, 6, 40, 80, generator=generator),
            "pick_pixel": torch.randint(0, 40, (1, 2), generator=generator),
            "place_pixel": torch.randint(0, 40, (1, 2), generator=generator),
            "rotation_bin": torch.randint(0, 36, (1,), generator=generator),
        }
        batch = {key: value.cuda() for key, value in batch.items()}
        eager.load_state_dict(graphed.state_dict())
        want_loss, want = _loss_and_gradients(eager, batch)
        loss, got = _loss_and_gradients(graphed, batch)
        assert loss == pytest.approx(want_loss, rel=1e-4)
        assert float((got - want).norm() / want.norm()) < 1e-4
        optimiser.step()


@needs_cuda
def test_second_call_before_backward_and_other_shapes_run_eagerly(monkeypatch):
    """A replay would overwrite the first call's activations: the gradients stay the eager ones."""
    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", False)
    torch.manual_seed(0)
    net = ResNet43_8s(6, 3, width=4).cuda()
    a, b, c = (torch.randn(2, 6, 16, 24, device="cuda") for _ in range(3))
    wide = torch.randn(1, 6, 16, 32, device="cuda")

    def gradients() -> list[torch.Tensor]:
        net.zero_grad()
        (net(a).square().sum() + 2 * net(b).square().sum() + net(wide).sum()).backward()
        return [p.grad.clone() for p in net.parameters()]

    expected = gradients()
    graph_training_passes(net)
    net(c).sum().backward()  # captures on this shape
    for got, want in zip(gradients(), expected, strict=True):
        assert torch.allclose(got, want, rtol=1e-4, atol=1e-5)
