import pytest
import torch

from nerf_transporter.imagery.losses import distortion
from nerf_transporter.imagery.render import RayOutput
from nerf_transporter.imagery.samplers import RaySamples

STEP = 0.01


def _output(samples: RaySamples, weights: torch.Tensor, floor_weight: torch.Tensor) -> RayOutput:
    rays = len(samples.bounds) - 1
    return RayOutput(
        colour=torch.zeros(rays, 3),
        depth=torch.zeros(rays),
        alpha=weights,
        floor_weight=floor_weight,
        weights=weights,
        samples=samples,
    )


def _brute_force(t, ray, weights, floor_distance, floor_weight) -> float:
    total = 0.0
    for r in range(len(floor_distance)):
        points = torch.cat([t[ray == r], floor_distance[r : r + 1]])
        mass = torch.cat([weights[ray == r], floor_weight[r : r + 1]])
        total += float(
            (mass[:, None] * mass[None, :] * (points[:, None] - points[None, :]).abs()).sum()
        )
        total += float(weights[ray == r].square().sum()) * STEP / 3.0
    return total / len(floor_distance)


def test_distortion_from_running_sums_equals_the_double_sum():
    generator = torch.Generator().manual_seed(0)
    counts = torch.tensor([5, 0, 3, 8])
    ray = torch.repeat_interleave(torch.arange(4), counts)
    t = torch.cat(
        [torch.sort(torch.rand(int(n), generator=generator) * 0.3).values for n in counts]
    )
    raw = torch.rand(len(t), generator=generator)
    weights = raw / (raw.sum() + 1.0)
    floor_weight = torch.rand(4, generator=generator) * 0.5
    floor_distance = torch.full((4,), 0.35)
    bounds = torch.searchsorted(ray, torch.arange(5))
    output = _output(RaySamples(t, ray, bounds), weights, floor_weight)
    assert float(distortion(output, STEP, floor_distance)) == pytest.approx(
        _brute_force(t, ray, weights, floor_distance, floor_weight), rel=1e-5
    )


def test_distortion_is_lowest_when_a_ray_stops_in_one_place():
    """All weight on the floor costs nothing; the same weight split between a shell in the air and
    the floor costs in proportion to the gap."""
    samples = RaySamples(torch.tensor([0.10, 0.30]), torch.tensor([0, 0]), torch.tensor([0, 2]))
    floor = torch.tensor([0.32])
    on_floor = _output(samples, torch.zeros(2), torch.ones(1))
    near_floor = _output(samples, torch.tensor([0.0, 0.5]), torch.tensor([0.5]))
    in_the_air = _output(samples, torch.tensor([0.5, 0.0]), torch.tensor([0.5]))
    assert float(distortion(on_floor, STEP, floor)) == 0.0
    assert float(distortion(near_floor, STEP, floor)) < float(distortion(in_the_air, STEP, floor))
