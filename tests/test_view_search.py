"""mira's view search measured (`evaluation.view_search`), its view-choice rules (`methods.mira`)
and MIRA's recipe knobs (`data.augment`, `data.datamodule`, configs/recipe/)."""

import json
import math

import numpy as np
import pytest
import torch

from nerf_transporter import geometry as g
from nerf_transporter.cli import lightning_main
from nerf_transporter.data.augment import sample_transform
from nerf_transporter.data.datamodule import Demo, DemoDataset
from nerf_transporter.data.labels import mira_labels, to_view_frames
from nerf_transporter.evaluation.callback import round_record_path, round_view_search
from nerf_transporter.evaluation.view_probe import offline_view_search
from nerf_transporter.evaluation.view_search import summary, view_search_record
from nerf_transporter.experiments.failures import view_search_by_outcome
from nerf_transporter.experiments.report import main as report_main
from nerf_transporter.methods import mira as mira_module
from nerf_transporter.methods.mira import PlaceSearch, view_scores
from tests.experiments.test_report import write_cell
from tests.helpers.synthetic import PIXEL_SIZE, SIZE
from tests.methods.test_methods import make_method
from tests.test_cli import closed_loop_test_config, fit_two_steps
from tests.test_cli import in_tmp_dir as in_tmp_dir  # noqa: F401  (an autouse fixture)


def test_the_chosen_view_ranks_first_and_ties_rank_in_index_order():
    search = PlaceSearch((0, 0), np.array([1.0, 3.0, 3.0, 2.0]), np.zeros((4, 3), dtype=int))
    assert search.chosen_view == 1
    assert [search.view_rank(v) for v in range(4)] == [3, 0, 1, 2]


def test_view_softmax_prefers_a_peaked_view_to_a_higher_flat_one():
    flat = torch.full((2, 8, 8), 5.0)
    flat[0, 0, 0] = 5.1  # the highest raw logit, among many nearly as high
    peaked = torch.full((2, 8, 8), -10.0)
    peaked[1, 3, 3] = 4.0  # lower, but alone
    unreachable = torch.full((2, 8, 8), -math.inf)
    logits = torch.stack([flat, peaked, unreachable])
    raw = view_scores(logits, "max_logit")
    own = view_scores(logits, "view_softmax")
    assert int(raw.argmax()) == 0 and int(own.argmax()) == 1
    assert -1e-3 < own[1] < 0  # the log of a probability of nearly 1
    assert own[2] == -math.inf and raw[2] == -math.inf  # no NaN from a view with no pixel


@pytest.mark.parametrize(("view_choice", "expected_view"), [("max_logit", 0), ("view_softmax", 1)])
def test_act_places_in_the_view_its_rule_ranks_first(monkeypatch, view_choice, expected_view):
    views = np.array([[0.0, 0.0], [0.0, math.pi / 12]])
    shape = g.image_shape(PIXEL_SIZE)
    flat_pixel, peak_pixel = (4, 2), (8, 5)

    def scores(query, kernel_f, crop_size):
        logits = torch.full((1, len(views), SIZE["n_rotations"], *shape), -10.0)
        logits[0, 0] = 5.0
        logits[0, 0, 2][flat_pixel] = 5.1
        logits[0, 1, 3][peak_pixel] = 4.0
        return logits

    monkeypatch.setattr(mira_module, "correlate_spectrum", scores)
    method = make_method("mira", view_chunk=len(views), view_choice=view_choice)
    height = np.full((len(views), *shape), 0.05, dtype=np.float32)
    colour = np.random.default_rng(0).integers(0, 256, (len(views), *shape, 3), dtype=np.uint8)
    observation = {"imagery": {"colour": colour, "height": height, "views": views}}
    action, search = method.act_with_search(observation)
    assert search.chosen_view == expected_view
    assert search.view_best.tolist() == [[2, *flat_pixel], [3, *peak_pixel]]
    labels = mira_labels(action, views, PIXEL_SIZE, SIZE["n_rotations"])
    assert labels.place_view == expected_view
    assert labels.place_pixel == (flat_pixel, peak_pixel)[expected_view]
    assert labels.rotation_bin == (2, 3)[expected_view]
    assert np.allclose(method.act(observation)["place"][0], action["place"][0])


def test_an_unknown_view_choice_is_refused():
    with pytest.raises(ValueError, match="view_choice must be one of max_logit, view_softmax"):
        make_method("mira", view_choice="best")


def tilted_truth(view: np.ndarray, pixel: tuple[int, int], yaw: float) -> dict:
    """An action whose place lies at `pixel` of a view with (roll, pitch) `view`, turned by yaw."""
    rotation = g.view_rotations(view[None])[0]
    position = g.view_to_world(g.pixel_to_world(np.array(pixel), 0.02, g.PIXEL_SIZE), rotation)
    place = (position, g.matrix_to_quat(rotation @ g.rot_z(yaw)))
    pick = (np.array([0.5, 0.0, 0.02]), np.array([0.0, 0.0, 0.0, 1.0]))
    return {"pick": pick, "place": place}


def test_the_record_names_the_true_view_its_rank_and_the_pixel_error():
    views = g.view_grid("normal")
    true, chosen = 30, 38  # (+10, +10) deg and (+20, +10) deg: one grid step apart in roll
    truth = tilted_truth(views[true], (100, 70), g.bin_to_angle(5, 36))
    scores = np.zeros(len(views))
    scores[chosen], scores[true], scores[3] = 3.0, 1.0, 2.0
    best = np.zeros((len(views), 3), dtype=int)
    best[true] = (7, 103, 74)  # 5 pixels and 2 bins off the label
    record = view_search_record(PlaceSearch((80, 80), scores, best), truth, views, g.PIXEL_SIZE, 36)
    assert record["true_view"] == pytest.approx(views[true].tolist())
    assert record["chosen_view"] == pytest.approx(views[chosen].tolist())
    assert record["true_view_rank"] == 2
    assert record["view_steps"] == 1
    assert record["true_view_pixel_error"] == pytest.approx(5.0)
    assert record["true_view_rotation_error"] == 2


def test_a_label_outside_the_image_leaves_the_pixel_error_unknown():
    views = g.view_grid("normal")
    truth = tilted_truth(views[24], (0, 0), 0.0)
    truth["place"] = (truth["place"][0] + np.array([1.0, 0.0, 0.0]), truth["place"][1])
    search = PlaceSearch((0, 0), np.arange(len(views), dtype=float), np.zeros((49, 3), dtype=int))
    record = view_search_record(search, truth, views, g.PIXEL_SIZE, 36)
    assert record["true_view"] == pytest.approx([0.0, 0.0])
    assert record["true_view_rank"] == 24  # views 25-48 score higher than the top-down view 24
    assert record["true_view_pixel_error"] is None


def test_summary_pools_the_records_of_an_evaluation():
    records = [
        {"view_steps": 0, "true_view_rank": 0},
        {"view_steps": 1, "true_view_rank": 2},
        {"view_steps": 3, "true_view_rank": 9},
        None,  # an erred episode
    ]
    assert summary(records) == {
        "view_top1": pytest.approx(1 / 3),
        "view_within_one_step": pytest.approx(2 / 3),
        "true_view_rank_median": 2.0,
        "view_search_episodes": 3.0,
    }
    assert summary([None]) is None


def test_gaussian_augmentation_draws_mira_spreads_and_uniform_stays_as_it_was():
    shape = g.image_shape(PIXEL_SIZE)
    rng = np.random.default_rng(0)
    drawn = [sample_transform(rng, shape, [], distribution="gaussian") for _ in range(4000)]
    angles = np.array([t.angle for t in drawn])
    shifts = np.array([t.shift for t in drawn])
    assert np.std(angles) == pytest.approx(math.pi / 3, rel=0.05)
    assert np.std(shifts, axis=0) == pytest.approx([min(shape) / 6] * 2, rel=0.05)
    # "uniform" (the default) draws as the table's fits did: angle, then row and column shifts
    rng, reference = np.random.default_rng(1), np.random.default_rng(1)
    uniform = sample_transform(rng, shape, [])
    assert uniform.angle == reference.uniform(-math.pi, math.pi)
    assert uniform.shift == (
        reference.uniform(-1, 1) * 0.5 * shape[0],
        reference.uniform(-1, 1) * 0.5 * shape[1],
    )
    with pytest.raises(ValueError, match="one of uniform, gaussian"):
        sample_transform(rng, shape, [], distribution="normal")


@pytest.mark.parametrize("negative_transform", ["shared", "own"])
def test_negative_views_move_with_the_sample_or_on_their_own(negative_transform):
    views = g.view_grid("normal")
    shape = g.image_shape(g.PIXEL_SIZE)
    rng = np.random.default_rng(0)
    truth = tilted_truth(views[30], (100, 70), 0.3)
    demo = Demo(
        seed=1,
        view_action=to_view_frames(truth, views),
        pick_view=g.top_down_view_index(views),
        colour=rng.integers(0, 256, (len(views), *shape, 3), dtype=np.uint8),
        height=rng.uniform(0.0, 0.05, (len(views), *shape)).astype(np.float32),
    )
    options = dict(pixel_size=g.PIXEL_SIZE, n_negative_views=3, views=views, augment=True)
    shared = DemoDataset([demo], "imagery", **options)[(0, 7)]
    sample = DemoDataset([demo], "imagery", negative_transform=negative_transform, **options)[
        (0, 7)
    ]
    assert torch.equal(sample["pick_image"], shared["pick_image"])
    assert torch.equal(sample["place_images"][0], shared["place_images"][0])
    negatives_equal = torch.equal(sample["place_images"][1:], shared["place_images"][1:])
    assert negatives_equal == (negative_transform == "shared")


def test_a_test_under_the_configs_view_choice_records_the_view_search(tmp_path, capsys):
    """`lightning test` takes the view choice from its config, not from the checkpoint, and every
    episode of mira records where its search placed against the true view."""
    run = fit_two_steps(tmp_path)
    (checkpoint,) = (run / "checkpoints").glob("*.ckpt")
    saved = torch.load(checkpoint, weights_only=True)["hyper_parameters"]
    assert saved["view_choice"] == "max_logit"
    overlay = tmp_path / "view_softmax.yaml"
    overlay.write_text("model: {init_args: {view_choice: view_softmax}}\n")
    config = closed_loop_test_config(tmp_path)
    argv = [
        "test",
        "--config",
        str(config),
        "--config",
        str(overlay),
        "--ckpt_path",
        str(checkpoint),
    ]
    assert lightning_main(argv) == 0
    record = json.loads((run / "checkpoints" / f"results-{checkpoint.stem}.json").read_text())
    assert record["test_time_options"] == {"view_choice": "view_softmax", "view_chunk": 8}
    episodes = record["episode_results"]
    assert len(episodes) == 2
    for episode in episodes:
        search = episode["view_search"]
        assert (search["true_view_rank"] == 0) == (search["view_steps"] == 0)
        assert len(search["true_view"]) == len(search["chosen_view"]) == 2
    assert record["view_search"] == summary([e["view_search"] for e in episodes])


def test_a_kept_validation_round_gives_its_view_search_figures(tmp_path):
    record = {"step": 500, "figures": {"eval/success_rate": 0.5, "eval/view_top1": 0.25}}
    record["figures"] |= {"eval/view_within_one_step": 0.75, "eval/true_view_rank_median": 2.0}
    path = round_record_path(tmp_path, 500)
    path.parent.mkdir()
    path.write_text(json.dumps(record))
    assert round_view_search(tmp_path, 500) == {
        "view_top1": 0.25,
        "view_within_one_step": 0.75,
        "true_view_rank_median": 2.0,
    }
    assert round_view_search(tmp_path, 1000) == {}  # no round kept: no figures


def test_validation_tables_show_the_view_search_of_the_rounds_and_the_test(tmp_path, capsys):
    results = tmp_path / "results"
    rounds = [(500, 0.2), (1000, 1.0)]
    write_cell(results, "mira", "hanging-disks", "normal", 40, 100, "nerf", rounds)
    path = results / "hanging-disks" / "mira.json"
    record = json.loads(path.read_text())
    record["validation"][1] |= {"view_top1": 0.5, "view_within_one_step": 0.9}
    record["validation"][1] |= {"true_view_rank_median": 1.0}
    record["view_search"] = {"view_top1": 0.4, "view_within_one_step": 0.8}
    record["view_search"] |= {"true_view_rank_median": 2.0, "view_search_episodes": 100.0}
    path.write_text(json.dumps(record))
    assert report_main([str(results), "--validation-tables"]) == 0
    view_table = capsys.readouterr().out.split("\n\n")[-1]
    assert view_table == (
        "| hanging-disks: view search | step 500 | step 1000 | test |\n"
        "| --- | --- | --- | --- |\n"
        "| mira (ours) | - | true view 50%, within one step 90%, median rank 1 "
        "| true view 40%, within one step 80%, median rank 2 |\n"
    )


def test_failures_split_the_view_search_by_outcome():
    def episode(success, steps, rank, pixels):
        search = {"view_steps": steps, "true_view_rank": rank, "true_view_pixel_error": pixels}
        return {"success": success, "error": None, "view_search": search}

    record = {
        "episode_results": [
            episode(True, 0, 0, 2.0),
            episode(True, 1, 1, 4.0),
            episode(False, 3, 12, 30.0),
            {"success": False, "error": "imagery", "view_search": None},
        ]
    }
    outcomes = view_search_by_outcome(record)
    assert outcomes["successes"] == {
        "view_top1": 0.5,
        "view_within_one_step": 1.0,
        "true_view_rank_median": 0.5,
        "view_search_episodes": 2.0,
        "median_true_view_pixel_error": 3.0,
    }
    assert outcomes["failures"]["view_top1"] == 0.0
    assert outcomes["failures"]["median_true_view_pixel_error"] == 30.0
    assert view_search_by_outcome({"episode_results": [{"success": True, "error": None}]}) is None


def test_the_offline_measure_ranks_the_true_view_and_the_label_in_it(monkeypatch):
    """With transport logits that put the label first in its view and that view first, both ranks
    are 0; with the label and its view scored below every other, both rank last."""
    views = np.array([[0.0, 0.0], [0.0, math.pi / 12], [math.pi / 12, 0.0]])
    shape = g.image_shape(PIXEL_SIZE)
    upright = np.array([0.0, 0.0, 0.0, 1.0])
    pick = (g.pixel_to_world(np.array([6, 3]), 0.02, PIXEL_SIZE), upright)
    rotation = g.view_rotations(views)[1]
    place_position = g.view_to_world(g.pixel_to_world(np.array([8, 4]), 0.02, PIXEL_SIZE), rotation)
    truth = {"pick": pick, "place": (place_position, g.matrix_to_quat(rotation))}
    rng = np.random.default_rng(0)
    demo = Demo(
        seed=1,
        view_action=to_view_frames(truth, views),
        pick_view=0,
        colour=rng.integers(0, 256, (len(views), *shape, 3), dtype=np.uint8),
        height=np.full((len(views), *shape), 0.02, dtype=np.float32),
    )
    labels = mira_labels(truth, views, PIXEL_SIZE, SIZE["n_rotations"])
    assert labels.place_view == 1

    def scores(label_logit):
        def correlate(query, kernel_f, crop_size):
            logits = torch.ones(1, len(views), SIZE["n_rotations"], *shape)
            logits[0, 1] = 0.0
            logits[0, 1, labels.rotation_bin][labels.place_pixel] = label_logit
            return logits

        return correlate

    method = make_method("mira", view_chunk=len(views), view_choice="max_logit")
    monkeypatch.setattr(mira_module, "correlate_spectrum", scores(9.0))
    figures = offline_view_search(method, [demo], views, PIXEL_SIZE, SIZE["n_rotations"])
    assert figures == {"true_view_rank_median": 0.0, "view_top1": 1.0, "label_rank_median": 0.0}
    monkeypatch.setattr(mira_module, "correlate_spectrum", scores(-9.0))
    figures = offline_view_search(method, [demo], views, PIXEL_SIZE, SIZE["n_rotations"])
    placements = SIZE["n_rotations"] * shape[0] * shape[1]
    assert figures["true_view_rank_median"] == 2.0 and figures["view_top1"] == 0.0
    # every other placement of its view over the workspace scores higher
    assert placements / 2 < figures["label_rank_median"] <= placements - 1
