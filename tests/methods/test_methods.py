import math

import lightning.pytorch as pl
import numpy as np
import pytest
import torch

from nerf_transporter import geometry as g
from nerf_transporter.data.seeds import seed_loader
from nerf_transporter.methods import METHODS, Method
from nerf_transporter.methods import mira as mira_module
from nerf_transporter.methods.mira import over_workspace, pixels_over_workspace
from tests.helpers.synthetic import (
    PIXEL_SIZE,
    SIZE,
    STATE_DIM,
    synthetic_batch,
    synthetic_observation,
    table_height_in_view,
)

pytestmark = pytest.mark.usefixtures("one_thread")


def make_method(name: str, **kwargs) -> Method:
    cls = METHODS[name]
    args = dict(state_dim=STATE_DIM) if cls.input_kind == "state" else dict(SIZE)
    return cls(**args, **kwargs)


@pytest.mark.parametrize("name", list(METHODS))
@pytest.mark.parametrize("batch_size", [1, 3])
def test_overfits_one_batch(name, batch_size):
    torch.manual_seed(0)
    method = make_method(name) if name == "gt_state_mlp" else make_method(name, lr=3e-3)
    batch = synthetic_batch(method.input_kind, batch_size)
    optimiser = method.configure_optimizers()
    with torch.no_grad():
        first = float(method.losses(batch)["loss"])
    for _ in range(300):
        loss = method.losses(batch)["loss"]
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        if float(loss.detach()) < first / 20:
            break
    with torch.no_grad():
        assert float(method.losses(batch)["loss"]) < first / 10


@pytest.mark.parametrize("name", list(METHODS))
def test_act_returns_valid_poses(name):
    torch.manual_seed(0)
    method = make_method(name)
    action = method.act(synthetic_observation(method.input_kind))
    assert set(action) == {"pick", "place"}
    for position, quat in action.values():
        assert position.shape == (3,) and quat.shape == (4,)
        assert np.isclose(np.linalg.norm(quat), 1.0)
    if method.input_kind != "state":
        assert np.allclose(action["pick"][1], [0, 0, 0, 1])  # upright suction pick
        assert g.BOUNDS[0, 0] <= action["pick"][0][0] <= g.BOUNDS[0, 1]


def test_mira_act_places_in_the_best_view():
    """The place pose is the global argmax over views, mapped back to the world through its view."""
    torch.manual_seed(0)
    method = make_method("mira", view_chunk=2)
    observation = synthetic_observation("imagery")
    imagery = observation["imagery"]
    action = method.act(observation)
    images = torch.from_numpy(imagery["colour"]).float()  # recompute the search by hand
    from nerf_transporter.data.preprocess import network_input

    images = network_input(imagery["colour"], imagery["height"])
    top = g.top_down_view_index(imagery["views"])
    with torch.no_grad():
        pick = torch.tensor([method.predict_pick(images[top : top + 1])])
        logits = method.transport(images[top : top + 1], pick, images[None])[0]
    view, rotation, row, col = np.unravel_index(int(logits.argmax()), logits.shape)
    rotation_v = g.view_rotations(imagery["views"])[view]
    height = float(imagery["height"][view, row, col])
    expected = g.view_to_world(g.pixel_to_world((row, col), height, PIXEL_SIZE), rotation_v)
    assert np.allclose(action["place"][0], expected, atol=1e-6)
    place_rotation = g.quat_to_matrix(action["place"][1])
    assert np.allclose(
        place_rotation,
        rotation_v @ g.rot_z(g.bin_to_angle(rotation, SIZE["n_rotations"])),
        atol=1e-6,
    )


def test_a_steep_view_sees_the_table_beyond_the_workspace_at_its_edges():
    everywhere = pixels_over_workspace(np.full(g.image_shape(), 0.1), np.eye(3))
    assert everywhere.all()
    # a roll turns y only: a row is over the workspace iff |y'| / cos(roll) <= 0.5
    roll = math.pi / 4
    rotation = g.tilt_matrix(roll, 0.0)
    over = pixels_over_workspace(table_height_in_view(rotation, g.PIXEL_SIZE), rotation)
    rows_over = over.all(axis=1)
    assert np.array_equal(rows_over, over.any(axis=1))
    inside = np.flatnonzero(rows_over)
    assert np.array_equal(inside, np.arange(inside[0], inside[-1] + 1))  # one band in the middle
    assert abs(len(inside) - over.shape[0] * math.cos(roll)) <= 2
    assert abs((inside[0] + inside[-1]) / 2 - (over.shape[0] - 1) / 2) <= 1


def test_mira_places_only_over_the_workspace(monkeypatch):
    """A steep view's best-scoring pixel that sees the table beyond the workspace is passed over
    for the best one over it."""
    views = np.array([[0.0, 0.0], [math.pi / 4, 0.0]])
    rotations = g.view_rotations(views)
    shape = g.image_shape(PIXEL_SIZE)
    height = np.stack([np.zeros(shape), table_height_in_view(rotations[1])]).astype(np.float32)
    beyond, over = (0, 4), (shape[0] // 2, 4)  # the steep view's edge row, its middle row
    assert not over_workspace(
        g.view_to_world(g.pixel_to_world(beyond, height[1][beyond], PIXEL_SIZE), rotations[1])
    )

    def scores(query, kernel_f, crop_size):
        logits = torch.zeros(1, len(views), SIZE["n_rotations"], *shape)
        logits[0, 1, 0][beyond] = 10.0
        logits[0, 1, 0][over] = 5.0
        return logits

    monkeypatch.setattr(mira_module, "correlate_spectrum", scores)
    method = make_method("mira", view_chunk=len(views))
    rng = np.random.default_rng(0)
    colour = rng.integers(0, 256, (len(views), *shape, 3), dtype=np.uint8)
    action = method.act({"imagery": {"colour": colour, "height": height, "views": views}})
    expected = g.view_to_world(g.pixel_to_world(over, height[1][over], PIXEL_SIZE), rotations[1])
    assert np.allclose(action["place"][0], expected, atol=1e-6)


def test_act_rejects_wrong_image_size():
    method = make_method("transporter_se2")
    observation = synthetic_observation("heightmap")
    observation["heightmap"]["height"] = observation["heightmap"]["height"][:-1]
    with pytest.raises(ValueError, match="pixel_size"):
        method.act(observation)


def test_a_test_without_a_callback_to_play_the_seeds_is_refused():
    trainer = pl.Trainer(logger=False, enable_progress_bar=False, accelerator="cpu")
    with pytest.raises(RuntimeError, match="no callback plays them"):
        trainer.test(make_method("mira"), dataloaders=seed_loader("test", 1))


@pytest.mark.parametrize("name", ["mira", "transporter_se2", "transporter_se3", "form2fit"])
def test_square_attention_is_rebuilt_from_a_checkpoint_and_acts_the_same(name):
    """A fit with configs/recipe/square_attention.yaml is tested padded, as it was trained."""
    torch.manual_seed(0)
    trained = make_method(name, square_attention=True)
    rebuilt = METHODS[name](**trained.hparams)
    rebuilt.load_state_dict(trained.state_dict())
    attentions = [m for m in rebuilt.modules() if type(m).__name__ == "Attention"]
    assert attentions and all(m.square_fill is not None for m in attentions)
    observation = synthetic_observation(trained.input_kind)
    first, again = trained.eval().act(observation), rebuilt.eval().act(observation)
    for key in ("pick", "place"):
        np.testing.assert_allclose(first[key][0], again[key][0])


def test_hyperparameters_are_plain_values():
    for name in METHODS:
        hparams = dict(make_method(name).hparams)
        assert all(isinstance(v, (int, float, str, bool, type(None))) for v in hparams.values()), (
            name
        )


# Losses and gradient norm of one step, recorded with the implementation before the training-speed
# work (commit 7bfdff0): speed changes must not change what is learned.
REFERENCE_STEP = {
    "mira": (30.02442169189453, 7.045197486877441, 22.979223251342773, 246.08302307128906),
    "transporter_se2": (
        29.32361602783203,
        7.045197486877441,
        22.278417587280273,
        245.9768829345703,
    ),
    "transporter_se3": (
        29.478042602539062,
        7.045426368713379,
        22.280961990356445,
        246.01763916015625,
    ),
    "form2fit": (15.098299026489258, 7.045187473297119, 7.0531110763549805, 0.2428598701953888),
}


@pytest.mark.parametrize("name", list(REFERENCE_STEP))
def test_step_matches_the_reference_implementation(name):
    """44 x 26 images (FFT lengths rounded up), 8 rotations, 16-pixel crops, width 4, seed 0."""
    torch.manual_seed(0)
    method = METHODS[name](width=4, n_rotations=8, crop_size=16)
    image = torch.randn(1, 6, 44, 26)
    batch = {
        "pick_pixel": torch.tensor([[20, 12]]),
        "place_pixel": torch.tensor([[30, 5]]),
        "rotation_bin": torch.tensor([3]),
    }
    if method.input_kind == "imagery":
        batch.update(pick_image=image, place_images=torch.randn(1, 2, 6, 44, 26))
    else:
        batch.update(
            image=image,
            place_z=torch.tensor([0.05]),
            place_roll=torch.tensor([0.1]),
            place_pitch=torch.tensor([-0.1]),
        )
    losses = method.losses(batch)
    losses["loss"].backward()
    grads = [p.grad.flatten() for p in method.parameters() if p.grad is not None]
    measured = (
        float(losses["loss"].detach()),
        float(losses["pick_loss"].detach()),
        float(losses["place_loss"].detach()),
        float(torch.cat(grads).norm()),
    )
    assert measured == pytest.approx(REFERENCE_STEP[name], rel=1e-5)
