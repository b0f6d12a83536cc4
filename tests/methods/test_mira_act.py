"""`Mira.act` on imagery whose views tell roll from pitch and whose top-down view is not the
first: the pick on the top-down view at its height, the place through the chosen view's
(roll, pitch) in that order."""

import numpy as np
import pytest
import torch

from nerf_transporter import geometry as g
from nerf_transporter.data.preprocess import network_input
from nerf_transporter.methods import mira as mira_module
from nerf_transporter.methods.mira import Mira
from tests.helpers.synthetic import PIXEL_SIZE, SIZE

pytestmark = pytest.mark.usefixtures("one_thread")

# (roll, pitch) of each view: none but the top-down one (index 2) has roll == pitch or roll == -pitch
VIEWS = np.array([[0.35, -0.17], [-0.17, 0.52], [0.0, 0.0], [0.52, 0.17], [-0.35, 0.0]])
TOP = 2


def _imagery(seed: int = 0) -> dict:
    """Random colour and heights 1-5 cm over VIEWS."""
    rng = np.random.default_rng(seed)
    shape = g.image_shape(PIXEL_SIZE)
    return {
        "colour": rng.integers(0, 256, (len(VIEWS), *shape, 3), dtype=np.uint8),
        "height": rng.uniform(0.01, 0.05, (len(VIEWS), *shape)).astype(np.float32),
        "views": VIEWS,
    }


def _place_pose(imagery: dict, view: int, rotation: int, pixel: tuple[int, int]):
    """The place pose of a label in `view`: through the view's own (roll, pitch)."""
    roll, pitch = VIEWS[view]
    view_rotation = g.tilt_matrix(roll, pitch)
    height = float(imagery["height"][view][pixel])
    position = g.view_to_world(g.pixel_to_world(pixel, height, PIXEL_SIZE), view_rotation)
    turn = view_rotation @ g.rot_z(g.bin_to_angle(rotation, SIZE["n_rotations"]))
    return position, turn


def test_the_top_down_view_is_found_wherever_it_lies():
    assert g.top_down_view_index(VIEWS) == TOP
    assert all(abs(roll) != abs(pitch) for index, (roll, pitch) in enumerate(VIEWS) if index != TOP)


def test_mira_picks_on_the_top_down_view_at_its_height(monkeypatch):
    """The pick attention and the transport's kernel see the top-down view (not the first), and
    the pick lies at that view's height at the pick pixel."""
    torch.manual_seed(0)
    method = Mira(**SIZE)
    imagery = _imagery()
    seen = []
    predict_pick, kernels = method.predict_pick, method.transport.kernels
    monkeypatch.setattr(
        method, "predict_pick", lambda image: seen.append(image) or predict_pick(image)
    )
    monkeypatch.setattr(
        method.transport,
        "kernels",
        lambda image, pixel: seen.append(image) or kernels(image, pixel),
    )
    action = method.act({"imagery": imagery})
    images = network_input(imagery["colour"], imagery["height"])
    assert len(seen) == 2 and all(torch.equal(image, images[TOP : TOP + 1]) for image in seen)
    with torch.no_grad():
        pick = predict_pick(images[TOP : TOP + 1])
    height = float(imagery["height"][TOP][pick])
    assert height >= 0.01  # a pick height of 0 (or another view's) is told apart
    expected = g.pixel_to_world(np.asarray(pick), height, PIXEL_SIZE)
    assert np.allclose(action["pick"][0], expected, atol=1e-6)
    assert action["pick"][0][2] == pytest.approx(height, abs=1e-6)
    assert np.allclose(action["pick"][1], [0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize("view", [0, 1, 3, 4])
def test_mira_places_through_the_chosen_views_roll_and_pitch(monkeypatch, view):
    """The transport's best score put in `view`: the place pose is that pixel seen through that
    view (roll about x, then pitch about y; swapping them moves and turns it)."""
    shape = g.image_shape(PIXEL_SIZE)
    pixel, rotation = (shape[0] // 2, shape[1] // 2), 1

    def scores(query, kernel_f, crop_size):
        logits = torch.zeros(1, query.shape[1], SIZE["n_rotations"], *shape)
        if 0 <= view - start[0] < query.shape[1]:
            logits[0, view - start[0], rotation][pixel] = 10.0
        start[0] += query.shape[1]
        return logits

    start = [0]
    monkeypatch.setattr(mira_module, "correlate_spectrum", scores)
    imagery = _imagery(seed=view)
    action = Mira(view_chunk=2, **SIZE).act({"imagery": imagery})
    position, turn = _place_pose(imagery, view, rotation, pixel)
    assert np.allclose(action["place"][0], position, atol=1e-6)
    assert np.allclose(g.quat_to_matrix(action["place"][1]), turn, atol=1e-6)
    swapped = g.view_to_world(
        g.pixel_to_world(pixel, float(imagery["height"][view][pixel]), PIXEL_SIZE),
        g.tilt_matrix(VIEWS[view][1], VIEWS[view][0]),
    )
    assert not np.allclose(swapped, position, atol=1e-3)  # the case tells the orders apart


def test_mira_places_at_the_argmax_of_the_real_transport():
    """Without a stand-in: the view the network's scores choose, by hand, is one that tells roll
    from pitch, and the place pose goes through it."""
    torch.manual_seed(0)
    method = Mira(view_chunk=2, **SIZE)
    imagery = _imagery(seed=1)
    action, search = method.act_with_search({"imagery": imagery})
    images = network_input(imagery["colour"], imagery["height"])
    with torch.no_grad():
        pick = torch.tensor([method.predict_pick(images[TOP : TOP + 1])])
        logits = method.transport(images[TOP : TOP + 1], pick, images[None])[0]
    view, rotation, row, col = np.unravel_index(int(logits.argmax()), logits.shape)
    assert view != TOP
    # the search evaluation records: this pick, and each view's best placement as integers
    assert search.pick == (int(pick[0, 0]), int(pick[0, 1]))
    assert search.chosen_view == view and search.view_best.dtype.kind == "i"
    assert tuple(search.view_best[view]) == (rotation, row, col)
    position, turn = _place_pose(imagery, int(view), int(rotation), (int(row), int(col)))
    assert np.allclose(action["place"][0], position, atol=1e-6)
    assert np.allclose(g.quat_to_matrix(action["place"][1]), turn, atol=1e-6)


def test_the_workspace_bounds_belong_to_the_workspace():
    """A point on the workspace's edge is over it (the view-search's reachable mask keeps it)."""
    (x_low, x_high), (y_low, y_high) = g.BOUNDS[0], g.BOUNDS[1]
    corners = np.array([[x, y, 0.1] for x in (x_low, x_high) for y in (y_low, y_high)])
    assert mira_module.over_workspace(corners).all()
    beyond = corners + np.array(
        [[-1e-9, -1e-9, 0], [-1e-9, 1e-9, 0], [1e-9, -1e-9, 0], [1e-9, 1e-9, 0]]
    )
    assert not mira_module.over_workspace(beyond).any()


def test_a_view_chunk_of_one_view_is_the_smallest():
    assert Mira(view_chunk=1, **SIZE).view_chunk == 1
    with pytest.raises(ValueError, match="view_chunk must be >= 1, got 0"):
        Mira(view_chunk=0, **SIZE)
