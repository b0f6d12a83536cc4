"""benchmarks/imagery.py: the grid's figures by view tilt, over the workspace and on object pixels."""

import json

import numpy as np
import pytest

from nerf_transporter import geometry
from nerf_transporter.evaluation.cache import ImageryCache
from nerf_transporter.evaluation.rollout import EvaluationSpec
from nerf_transporter.imagery.metrics import colour_edges
from nerf_transporter.methods.mira import pixels_over_workspace
from nerf_transporter.splits import split_seed
from tests.helpers.benchmarks import load_benchmark


def test_height_error_is_binned_by_the_tilt_of_each_view():
    script = load_benchmark("imagery")
    normal, challenging = geometry.view_grid("normal"), geometry.view_grid("challenging")
    top_down_only = np.zeros(len(normal))
    top_down_only[geometry.top_down_view_index(normal)] = 7.0
    bins = script.mean_by_view_tilt(normal, list(top_down_only))
    assert bins["0-10"] == 7.0  # the 7 x 7 grid's only view under 10 deg is the top-down one
    assert list(bins) == ["0-10", "10-20", "20-30", "30-40", "40-90"]
    assert bins["10-20"] == bins["40-90"] == 0.0
    twenty = [v for v, view in enumerate(normal) if np.allclose(view, (np.radians(20.0), 0.0))]
    assert len(twenty) == 1
    only_twenty = np.zeros(len(normal))
    only_twenty[twenty] = 9.0
    assert script.mean_by_view_tilt(normal, list(only_twenty))["10-20"] == 0.0
    tilts = [np.degrees(np.arccos(geometry.tilt_matrix(*v)[2, 2])) for v in challenging]
    assert [script.view_tilt_deg(*v) for v in challenging] == pytest.approx(tilts)
    assert max(tilts) == pytest.approx(60.0)  # roll and pitch 45 deg
    steepest = [float(np.isclose(tilt, 60.0)) for tilt in tilts]  # the four 45 / 45 deg corners
    assert sum(steepest) == 4 and script.mean_by_view_tilt(challenging, steepest)["40-90"] > 0
    by_tilt = script.mean_by_view_tilt(challenging, tilts)
    for name, mean_tilt in by_tilt.items():
        low, high = map(float, name.split("-"))
        assert low <= mean_tilt < high


def _view_surface(rotation: np.ndarray, world_height: np.ndarray) -> np.ndarray:
    """The view height (along the view's axis) at each pixel of a surface standing
    `world_height` [H, W] above the table in the world (a point P' maps to c + R (P' - c))."""
    rows, cols = world_height.shape
    x = geometry.BOUNDS[0, 0] + np.arange(cols)[None, :] * geometry.PIXEL_SIZE
    y = geometry.BOUNDS[1, 0] + np.arange(rows)[:, None] * geometry.PIXEL_SIZE
    centre = geometry.WORKSPACE_CENTER
    tilt = rotation[2, 0] * (x - centre[0]) + rotation[2, 1] * (y - centre[1])
    return ((world_height - centre[2] - tilt) / rotation[2, 2] + centre[2]).astype(np.float32)


def test_object_figures_cover_the_pixels_of_objects_standing_on_the_table_in_a_tilted_view():
    script = load_benchmark("imagery")
    rotation = geometry.tilt_matrix(np.radians(30.0), 0.0)
    rows, cols = geometry.image_shape()
    world_height = np.zeros((rows, cols))
    block = (slice(150, 171), slice(70, 91))  # about the workspace centre
    world_height[block] = 0.03
    beyond = (slice(0, 4), slice(70, 91))  # an object whose pixels see past the workspace
    world_height[beyond] = 0.05
    truth_height = _view_surface(rotation, world_height)
    # the tilted table itself stands up to 0.29 m along the view's axis: a threshold on the view's
    # height would take it for objects
    assert (truth_height[world_height == 0] > 0.005).mean() > 0.4
    workspace = pixels_over_workspace(truth_height, rotation)
    assert workspace[block].all() and not workspace[beyond].any()
    on_block = np.zeros((rows, cols), bool)
    on_block[block] = True

    height = truth_height + np.where(on_block, 0.004, 0.010).astype(np.float32)
    height[beyond] += 0.5
    truth_colour = np.full((rows, cols, 3), 120, np.uint8)
    colour = truth_colour + np.where(on_block, 10, 30).astype(np.uint8)[..., None]
    errors = script.view_errors(colour, height, truth_colour, truth_height, rotation, 0.003125)

    assert errors["object_height_mae_mm"] == pytest.approx(4.0, abs=1e-3)
    assert errors["object_psnr_db"] == pytest.approx(20 * np.log10(255 / 10))
    blocks, tables = on_block[workspace].sum(), (~on_block)[workspace].sum()
    expected = (4.0 * blocks + 10.0 * tables) / (blocks + tables)
    assert errors["workspace_height_mae_mm"] == pytest.approx(expected, abs=1e-3)
    assert errors["workspace_psnr_db"] == pytest.approx(
        10 * np.log10(255**2 * (blocks + tables) / (100 * blocks + 900 * tables))
    )

    bare = script.view_errors(
        colour, height, truth_colour, _view_surface(rotation, 0 * world_height), rotation, 0.003125
    )
    assert np.isnan(bare["object_height_mae_mm"]) and np.isnan(bare["object_psnr_db"])


def test_views_without_object_pixels_are_left_out_of_their_tilt_bin():
    script = load_benchmark("imagery")
    normal = geometry.view_grid("normal")
    values = [float("nan")] * len(normal)
    values[geometry.top_down_view_index(normal)] = 3.0
    assert script.mean_by_view_tilt(normal, values) == {"0-10": 3.0}


def _cache_scene(cache: ImageryCache, spec: EvaluationSpec, seed: int, colour, height) -> None:
    views = geometry.view_grid(spec.setting)
    cache.save(
        spec.task,
        spec.setting,
        seed,
        spec.imagery_key(),
        {"colour": colour, "height": height, "views": views},
    )


def test_cached_imagery_is_scored_against_the_simulators_with_its_edges_apart(tmp_path, capsys):
    """`--cached`: a candidate's imagery already in the cache is scored without a fit, and its
    colour error at the true colour's edges is told from the error elsewhere."""
    script = load_benchmark("imagery")
    grid = geometry.view_grid("normal")
    rows, cols = geometry.image_shape()
    world_height = np.zeros((rows, cols))
    world_height[150:171, 70:91] = 0.03
    truth_height = np.stack(
        [_view_surface(geometry.tilt_matrix(*view), world_height) for view in grid]
    )
    truth_colour = np.full((len(grid), rows, cols, 3), 120, np.uint8)
    truth_colour[:, 150:171, 70:91] = (200, 40, 40)
    edges = np.stack([colour_edges(image) for image in truth_colour])
    colour = truth_colour + np.where(edges, 30, 2).astype(np.uint8)[..., None]
    options = {"iterations": 800}
    cache = ImageryCache(tmp_path)
    seed = split_seed("test", 0)
    nerf = EvaluationSpec("place-red-in-green", imagery="nerf", imagery_config=options)
    oracle = EvaluationSpec("place-red-in-green", imagery="oracle")
    _cache_scene(cache, nerf, seed, colour, truth_height)
    _cache_scene(cache, oracle, seed, truth_colour, truth_height)

    argv = ["--task", "place-red-in-green", "--episodes", "1", "--cached", str(tmp_path)]
    assert script.main([*argv, "--imagery-option", "iterations=800", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert summary["episodes"] == 1 and summary["height_mae_mm"] == 0.0
    assert summary["object_footprint_iou"] == 1.0  # the top-down block, neither fatter nor thinner
    assert summary["object_footprint_extra_px"] == summary["object_footprint_missing_px"] == 0
    edge, flat = summary["edge_psnr_by_view_tilt_db"], summary["flat_psnr_by_view_tilt_db"]
    assert list(edge) == list(flat) == ["0-10", "10-20", "20-30", "30-40", "40-90"]
    assert list(edge.values()) == pytest.approx([20 * np.log10(255 / 30)] * 5)
    assert list(flat.values()) == pytest.approx([20 * np.log10(255 / 2)] * 5)
    with pytest.raises(SystemExit, match="no cached nerf imagery .* iterations=400.*cache-imagery"):
        script.main([*argv, "--imagery-option", "iterations=400"])
    with pytest.raises(SystemExit, match="test seed"):
        script.main([*argv[:3], "2", *argv[4:], "--imagery-option", "iterations=800"])
