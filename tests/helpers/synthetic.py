"""Tiny synthetic batches and observations in the layout of docs/interfaces.md (no simulator)."""

import numpy as np
import torch

from nerf_transporter import geometry as g

# Tiny models: pixel size 0.0625 m -> 16 x 8 images.
PIXEL_SIZE = 0.0625
SIZE = dict(pixel_size=PIXEL_SIZE, n_rotations=4, crop_size=8, width=8)
STATE_DIM = 10


def synthetic_batch(input_kind: str, batch_size: int, n_views: int = 2, seed: int = 0) -> dict:
    """A batch in the layout of docs/interfaces.md with random content and labels."""
    gen = torch.Generator().manual_seed(seed)
    height, width = g.image_shape(PIXEL_SIZE)

    def pixels():
        rows = torch.randint(0, height, (batch_size,), generator=gen)
        cols = torch.randint(0, width, (batch_size,), generator=gen)
        return torch.stack([rows, cols], dim=1)

    if input_kind == "state":
        quats = torch.nn.functional.normalize(torch.randn(batch_size, 2, 4, generator=gen), dim=-1)
        xyz = torch.rand(batch_size, 2, 3, generator=gen)
        return {
            "state": torch.randn(batch_size, STATE_DIM, generator=gen),
            "pick": torch.cat([xyz[:, 0], quats[:, 0]], dim=1),
            "place": torch.cat([xyz[:, 1], quats[:, 1]], dim=1),
        }
    batch = {
        "pick_pixel": pixels(),
        "place_pixel": pixels(),
        "rotation_bin": torch.randint(0, SIZE["n_rotations"], (batch_size,), generator=gen),
    }
    if input_kind == "imagery":
        batch["pick_image"] = torch.randn(batch_size, 6, height, width, generator=gen)
        batch["place_images"] = torch.randn(batch_size, n_views, 6, height, width, generator=gen)
    else:
        batch["image"] = torch.randn(batch_size, 6, height, width, generator=gen)
        batch["place_z"] = 0.1 * torch.rand(batch_size, generator=gen)
        batch["place_roll"] = torch.rand(batch_size, generator=gen) - 0.5
        batch["place_pitch"] = torch.rand(batch_size, generator=gen) - 0.5
    return batch


def synthetic_observation(input_kind: str, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    shape = g.image_shape(PIXEL_SIZE)
    if input_kind == "state":
        return {"state": rng.normal(size=STATE_DIM).astype(np.float32)}
    if input_kind == "heightmap":
        return {
            "heightmap": {
                "colour": rng.integers(0, 256, (*shape, 3), dtype=np.uint8),
                "height": rng.uniform(0, 0.05, shape).astype(np.float32),
            }
        }
    views = g.view_grid("normal")[::8]  # 7 views including the top-down one
    return {
        "imagery": {
            "colour": rng.integers(0, 256, (len(views), *shape, 3), dtype=np.uint8),
            "height": rng.uniform(0, 0.05, (len(views), *shape)).astype(np.float16),
            "views": views,
        }
    }


def table_height_in_view(view_rotation: np.ndarray, pixel_size: float = PIXEL_SIZE) -> np.ndarray:
    """The height image of the bare table (world z = 0) as a view with this rotation sees it."""
    pixels = np.stack(np.indices(g.image_shape(pixel_size)), axis=-1)
    offset = g.pixel_to_world(pixels, 0.0, pixel_size) - g.WORKSPACE_CENTER
    normal = view_rotation.T @ np.array([0.0, 0.0, 1.0])  # the table's normal in the view frame
    return (
        g.WORKSPACE_CENTER[2]
        - (offset[..., 0] * normal[0] + offset[..., 1] * normal[1]) / normal[2]
    )
