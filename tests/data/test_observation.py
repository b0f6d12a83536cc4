"""One scene spec behind the generator's config and the evaluator's spec, and one observation
builder: a seed generated for training and the same seed evaluated are seen alike."""

import re

import numpy as np
import pytest

from nerf_transporter import geometry as g
from nerf_transporter.data import episode as ep
from nerf_transporter.data import observation as observation_module
from nerf_transporter.data.generate import GenerationConfig, generate_dataset
from nerf_transporter.data.heightmap import heightmap_from_rgbd
from nerf_transporter.data.observation import SceneSpec, observation, reference_imagery_options
from nerf_transporter.evaluation.rollout import EvaluationSpec, Evaluator
from nerf_transporter.imagery import ImageryConfig
from nerf_transporter.splits import split_seed

PIXEL = 0.0125
NERF_SCENE = SceneSpec("block-insertion", "normal", "nerf", PIXEL, 6, (60, 80), {"iterations": 30})


def test_both_configs_are_built_from_one_scene():
    config = GenerationConfig(scene=NERF_SCENE, split="validation")
    assert config == GenerationConfig(
        "block-insertion", "normal", "validation", "nerf", PIXEL, 6, (60, 80), {"iterations": 30}
    )
    assert (config.task, config.split, config.nerf_image_size) == (
        "block-insertion",
        "validation",
        (60, 80),
    )
    spec = EvaluationSpec(scene=NERF_SCENE, cache_dir=None)
    assert spec.scene is config.scene and spec.grid.shape == (49, 2)
    by_fields = EvaluationSpec(
        task="block-insertion",
        pixel_size=PIXEL,
        nerf_views=6,
        nerf_image_size=(60, 80),
        imagery_config=ImageryConfig(pixel_size=PIXEL, iterations=30),
        cache_dir=None,
    )
    assert by_fields.imagery_config() == spec.imagery_config() == config.imagery_config()
    assert by_fields.imagery_key() == spec.imagery_key()
    # what the dataset records of its imagery is what keys the evaluation cache
    assert config.description()["imagery"]["config"] == NERF_SCENE.imagery_description()


def test_runtime_imagery_options_change_neither_the_dataset_nor_the_cache_key():
    fast = SceneSpec(
        "block-insertion", pixel_size=PIXEL, imagery_options={"device": "cpu", "threads": 1}
    )
    plain = SceneSpec("block-insertion", pixel_size=PIXEL)
    assert fast.imagery_description() == plain.imagery_description()
    assert EvaluationSpec(scene=fast).imagery_key() == EvaluationSpec(scene=plain).imagery_key()
    assert fast.imagery_description()["iterations"] == ImageryConfig().iterations


def test_the_reference_imagery_keeps_every_dataset_and_cache_key_it_was_built_under():
    """colour_init came after the datasets and caches were built under its "grey": at that value
    it is left out of their descriptions. The reference imagery (grey, sparsity 0.003) keeps the
    plain names; the default (the table-colour start) is another dataset and cache entry, named
    with a hash of its changes."""
    reference = {"colour_init": "grey", "sparsity_weight": 0.003}
    plain = SceneSpec("block-insertion", pixel_size=PIXEL, imagery_options=reference)
    full = SceneSpec(
        "block-insertion", pixel_size=PIXEL, imagery_options=reference_imagery_options()
    )
    default = SceneSpec("block-insertion", pixel_size=PIXEL)
    assert "colour_init" not in plain.imagery_description()
    assert full.imagery_description() == plain.imagery_description()
    assert default.imagery_description() == plain.imagery_description() | {
        "colour_init": "table",
        "sparsity_weight": 0.0003,
    }
    keys = {EvaluationSpec(scene=scene).imagery_key() for scene in (plain, full, default)}
    assert len(keys) == 2
    names = [GenerationConfig(scene=scene).dataset_name() for scene in (plain, full, default)]
    assert names[0] == names[1] == "block-insertion-normal-train-px0.0125"
    assert re.fullmatch(r"block-insertion-normal-train-px0\.0125-imagery[0-9a-f]{8}", names[2])
    assert plain.imagery_changes() == {}
    assert default.imagery_changes() == {"colour_init": "table", "sparsity_weight": 0.0003}


def test_a_changed_imagery_default_names_data_of_its_own(monkeypatch):
    """The reference imagery, not the code's defaults, names the data: were a default of the
    imagery's settings changed, the data built with it would not take the reference's name."""
    plain = SceneSpec("block-insertion", pixel_size=PIXEL)
    default_name = GenerationConfig(scene=plain).dataset_name()
    monkeypatch.setitem(observation_module.REFERENCE_IMAGERY, "iterations", 300)
    assert plain.imagery_changes()["iterations"] == ImageryConfig().iterations
    assert GenerationConfig(scene=plain).dataset_name() != default_name
    monkeypatch.setitem(observation_module.REFERENCE_IMAGERY, "stage_scales", (8, 2, 1))
    assert plain.imagery_changes()["stage_scales"] == [4, 2, 1]  # as JSON gives it back


def test_bad_scenes_are_refused():
    with pytest.raises(ValueError, match="imagery config pixel_size 0.003125 differs"):
        SceneSpec("block-insertion", pixel_size=PIXEL, imagery_options={"pixel_size": 0.003125})
    with pytest.raises(ValueError, match="unknown imagery 'depth'"):
        EvaluationSpec(task="block-insertion", imagery="depth")
    with pytest.raises(ValueError, match="unknown split 'dev'"):
        GenerationConfig(scene=NERF_SCENE, split="dev")
    with pytest.raises(TypeError, match="not both"):
        GenerationConfig("block-insertion", scene=NERF_SCENE)
    with pytest.raises(TypeError, match="not both"):
        EvaluationSpec(scene=NERF_SCENE, pixel_size=PIXEL)
    with pytest.raises(ValueError, match="unknown input_kind 'pointcloud'"):
        observation("pointcloud", NERF_SCENE, None, {})


class Recorder:
    """A policy that keeps its observations and acts nowhere useful."""

    training = False

    def __init__(self, input_kind):
        self.input_kind = input_kind
        self.observations = []

    def train(self, mode=True):
        return self

    def act(self, observation):
        self.observations.append(observation)
        upright = np.array([0.0, 0.0, 0.0, 1.0])
        return {
            "pick": (np.array([0.5, 0.0, 0.02]), upright),
            "place": (np.array([0.5, 0.2, 0.02]), upright),
        }


def test_a_generated_seed_and_the_same_seed_evaluated_are_seen_alike(tmp_path):
    pytest.importorskip("pybullet")
    scene = SceneSpec("block-insertion", imagery="oracle", pixel_size=PIXEL, nerf_views=0)
    dataset = generate_dataset(GenerationConfig(scene=scene), 1, tmp_path, progress=False)
    (ref,) = ep.list_episodes(dataset)
    stored = ep.load_episode(ref.path).arrays
    assert ref.seed == split_seed("train", ref.index)
    seen = {}
    with Evaluator(EvaluationSpec(scene=scene, cache_dir=None)) as evaluator:
        for kind in ("imagery", "heightmap"):
            policy = Recorder(kind)
            assert evaluator.run_episode(policy, ref.seed).error is None
            (seen[kind],) = (observation[kind] for observation in policy.observations)
    imagery = seen["imagery"]
    assert imagery["colour"].shape == (49, *g.image_shape(PIXEL), 3)
    np.testing.assert_array_equal(imagery["colour"], stored["imagery"]["colour"])
    assert imagery["height"].dtype == np.float32  # the stored float16 values
    np.testing.assert_array_equal(imagery["height"], stored["imagery"]["height"])
    np.testing.assert_array_equal(imagery["views"].astype(np.float32), stored["imagery"]["views"])
    colour, height = heightmap_from_rgbd(stored["rgbd"], PIXEL)
    np.testing.assert_array_equal(seen["heightmap"]["colour"], colour)
    np.testing.assert_array_equal(seen["heightmap"]["height"], height)


def test_the_distortion_loss_names_data_of_its_own_only_when_on():
    """distortion_weight came after every dataset was built: at 0 (off) their names stay."""
    default = SceneSpec("block-insertion", pixel_size=PIXEL)
    off = SceneSpec("block-insertion", pixel_size=PIXEL, imagery_options={"distortion_weight": 0.0})
    on = SceneSpec("block-insertion", pixel_size=PIXEL, imagery_options={"distortion_weight": 0.01})
    assert off.imagery_changes() == default.imagery_changes()
    assert on.imagery_changes() == default.imagery_changes() | {"distortion_weight": 0.01}
    names = {GenerationConfig(scene=scene).dataset_name() for scene in (default, off, on)}
    assert len(names) == 2
