import math

import pytest
import torch

from nerf_transporter import geometry
from nerf_transporter.imagery import ImageryConfig
from nerf_transporter.imagery.fields import DenseGridField, FloorMap
from nerf_transporter.imagery.rays import orthographic_rays, perspective_rays
from nerf_transporter.imagery.render import MarchSettings, render_rays
from nerf_transporter.imagery.samplers import OccupancyGrid, RaySamples, occupied_samples
from nerf_transporter.imagery.synthetic import ring_cameras

SEGMENT = 0.05


def _packed() -> RaySamples:
    # ray 0: three samples, ray 1: none, ray 2: two samples
    return RaySamples(
        t=torch.tensor([0.1, 0.2, 0.3, 0.5, 0.6]),
        ray=torch.tensor([0, 0, 0, 2, 2]),
        bounds=torch.tensor([0, 3, 3, 5]),
    )


def test_ray_sums_and_exclusive_sums_stay_within_each_ray():
    samples = _packed()
    values = torch.tensor([1.0, 2.0, 3.0, 10.0, 20.0])
    assert torch.equal(samples.ray_sums(values), torch.tensor([6.0, 0.0, 30.0]))
    assert torch.equal(samples.exclusive_sums(values), torch.tensor([0.0, 1.0, 3.0, 0.0, 10.0]))
    pairs = torch.stack([values, -values], dim=1)
    assert torch.equal(samples.ray_sums(pairs), torch.tensor([[6.0, -6.0], [0, 0], [30, -30]]))
    kept = samples.select(torch.tensor([False, True, True, True, False]))
    assert torch.equal(kept.bounds, torch.tensor([0, 2, 2, 3]))
    assert torch.equal(kept.ray_sums(torch.ones(3)), torch.tensor([2.0, 0.0, 1.0]))


def test_ray_sums_pass_gradients():
    values = torch.tensor([1.0, 2.0, 3.0, 10.0, 20.0], requires_grad=True)
    _packed().exclusive_sums(values).sum().backward()
    assert torch.equal(values.grad, torch.tensor([2.0, 1.0, 0.0, 1.0, 0.0]))


def _occupancy_with_one_cell() -> OccupancyGrid:
    occupancy = OccupancyGrid((10, 20, 7))
    mask = torch.zeros(7, 20, 10, dtype=torch.bool)
    mask[1:3, 9:12, 4:7] = True
    occupancy.set_mask(mask)
    return occupancy


def _rays():
    intrinsics, poses = ring_cameras(3, (12, 16), 10.0)
    count = 3 * 12 * 16
    camera = torch.arange(count) // (12 * 16)
    pixel = torch.arange(count) % (12 * 16)
    return perspective_rays(
        torch.as_tensor(intrinsics), torch.as_tensor(poses), camera, pixel // 16, pixel % 16
    )


def test_samples_lie_in_occupied_segments_in_order():
    rays, occupancy = _rays(), _occupancy_with_one_cell()
    samples = occupied_samples(rays, occupancy, SEGMENT, 4)
    assert 0 < len(samples) < 4 * len(rays)
    assert torch.all(samples.ray[1:] >= samples.ray[:-1])
    same_ray = samples.ray[1:] == samples.ray[:-1]
    assert torch.all(samples.t[1:][same_ray] > samples.t[:-1][same_ray])
    assert torch.equal(samples.bounds, torch.searchsorted(samples.ray, torch.arange(len(rays) + 1)))
    assert torch.all(samples.t < rays.far[samples.ray])
    # every sample is within half a segment of an occupied segment midpoint: near an occupied cell
    points = rays.origins[samples.ray] + samples.t[:, None] * rays.directions[samples.ray]
    low, high = occupancy.bbox
    margin = SEGMENT
    assert torch.all((points > low - margin) & (points < high + margin))


def test_jittered_samples_are_reproducible_and_stay_in_their_strata():
    rays, occupancy = _rays(), _occupancy_with_one_cell()
    centres = occupied_samples(rays, occupancy, SEGMENT, 4)
    first = occupied_samples(rays, occupancy, SEGMENT, 4, torch.Generator().manual_seed(3))
    second = occupied_samples(rays, occupancy, SEGMENT, 4, torch.Generator().manual_seed(3))
    other = occupied_samples(rays, occupancy, SEGMENT, 4, torch.Generator().manual_seed(4))
    assert torch.equal(first.t, second.t) and not torch.equal(first.t, other.t)
    # these rays end far beyond the occupied cells: jitter drops no sample
    assert torch.equal(first.ray, centres.ray)
    assert torch.all((first.t - centres.t).abs() <= SEGMENT / 8 + 1e-6)


def test_full_occupancy_samples_the_whole_box_interval():
    rays = orthographic_rays(0.0, 0.0, pixel_size=0.05)
    occupancy = OccupancyGrid((10, 20, 7))
    samples = occupied_samples(rays, occupancy, SEGMENT, 2)
    height = float(geometry.BOUNDS[2, 1])
    step = SEGMENT / 2
    centres = (torch.arange(math.ceil(height / step)) + 0.5) * step  # those above the floor
    per_ray = samples.bounds[1:] - samples.bounds[:-1]
    assert torch.all(per_ray == int((centres < height).sum()))


def test_rendering_matches_a_dense_reference():
    """The packed renderer equals plain alpha compositing of every sample along each ray."""
    torch.manual_seed(0)
    field = DenseGridField((10, 20, 8), 0.05, colour_downscale=1, initial_thickness=0.3)
    with torch.no_grad():
        field.density_grid.normal_(0.0, 2.0)
        field.colour_grid.normal_()
    floor = FloorMap(0.05, torch.tensor([0.2, 0.4, 0.6]))
    rays = orthographic_rays(0.3, -0.2, pixel_size=0.05)
    occupancy = OccupancyGrid((10, 20, 7))
    settings = MarchSettings(SEGMENT, 4, weight_threshold=0.0)
    colour, depth = render_rays(field, floor, occupancy, rays, settings)
    median_colour, median = render_rays(
        field, floor, occupancy, rays, settings, depth="median", colour="median"
    )
    samples = occupied_samples(rays, occupancy, SEGMENT, 4)
    expected_colour, expected_depth, expected_median = [], [], []
    expected_median_colour = []
    with torch.no_grad():
        for r in range(len(rays)):
            t = samples.t[samples.ray == r]
            points = rays.origins[r] + t[:, None] * rays.directions[r]
            tau = field.density(points) * settings.step
            transmittance = torch.exp(-(torch.cumsum(tau, 0) - tau))
            weights = transmittance * (1.0 - torch.exp(-tau))
            left = torch.exp(-tau.sum())
            hit = rays.origins[r] + rays.floor[r] * rays.directions[r]
            expected_colour.append(
                (weights[:, None] * field.colour(points)).sum(0) + left * floor(hit[None])[0]
            )
            expected_depth.append((weights * t).sum() + left * rays.floor[r])
            # the median: the first sample whose accumulated weight reaches one half, else the floor
            reached = torch.nonzero(torch.cumsum(weights, 0) >= 0.5)
            expected_median.append(t[reached[0, 0]] if len(reached) else rays.floor[r])
            # its colour: the field's at that sample, else the floor's where the ray meets it
            surface = rays.origins[r] + expected_median[-1] * rays.directions[r]
            expected_median_colour.append(
                field.colour(surface[None])[0] if len(reached) else floor(surface[None])[0]
            )
    assert torch.allclose(colour, torch.stack(expected_colour), atol=1e-5)
    assert torch.allclose(depth, torch.stack(expected_depth), atol=1e-5)
    expected_median = torch.stack(expected_median)
    assert torch.equal(median, expected_median)
    # this random field has rays of each kind: the median on a sample, and on the floor
    assert 0 < int((expected_median == rays.floor).sum()) < len(rays)
    assert torch.allclose(median_colour, torch.stack(expected_median_colour), atol=1e-6)
    with pytest.raises(ValueError, match="unknown depth estimate 'mode'"):
        render_rays(field, floor, occupancy, rays, settings, depth="mode")
    with pytest.raises(ValueError, match="unknown colour estimate 'mode'"):
        render_rays(field, floor, occupancy, rays, settings, colour="mode")


@pytest.mark.parametrize(("device", "expected"), [("cpu", 1 << 16), ("cuda", 1 << 19)])
def test_render_batch_is_chosen_per_device(device, expected):
    assert ImageryConfig().render_rays_per_call(torch.device(device)) == expected
    assert ImageryConfig(render_batch=1000).render_rays_per_call(torch.device(device)) == 1000
    with pytest.raises(ValueError, match="render_batch"):
        ImageryConfig(render_batch=-1)


def test_an_unknown_depth_estimate_is_refused_by_the_config():
    assert ImageryConfig(depth="median").depth == "median"
    with pytest.raises(ValueError, match="unknown depth 'mode'"):
        ImageryConfig(depth="mode")
    with pytest.raises(ValueError, match="unknown colour 'mode'"):
        ImageryConfig(colour="mode")
