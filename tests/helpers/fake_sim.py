"""A small deterministic stand-in for the simulator (fast generation and DataModule tests)."""

import math

import numpy as np

from nerf_transporter import geometry as g

PIXEL = 0.0125
MARK = 255


def fake_action(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    pick = (
        np.array([rng.uniform(0.35, 0.65), rng.uniform(-0.35, -0.05), 0.04]),
        np.array([0, 0, 0, 1.0]),
    )
    place = (
        np.array([rng.uniform(0.35, 0.65), rng.uniform(0.05, 0.35), rng.uniform(0.03, 0.1)]),
        g.euler_to_quat(*rng.uniform(-math.pi / 6, math.pi / 6, 2), rng.uniform(0, 2 * math.pi)),
    )
    return {"pick": pick, "place": place}


class FakeTask:
    def oracle(self, env):
        return fake_action(env.seed)


class FakeEnv:
    """Deterministic stand-in: seeds whose index is 1 mod 4 fail; the orthographic view of (roll,
    pitch) marks the pick position (top-down view) and the place position (every view)."""

    task = FakeTask()

    def reset(self, seed):
        self.seed = seed
        rng = np.random.default_rng(seed)
        camera = np.eye(4)
        camera[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down
        camera[:3, 3] = [0.5, 0.0, 1.0]
        obs = {
            "state": rng.normal(size=14).astype(np.float32),
            "rgbd": {
                "rgb": rng.integers(0, 255, (3, 12, 16, 3), dtype=np.uint8),
                "depth": np.full((3, 12, 16), 1.0, dtype=np.float32),
                "intrinsics": np.tile(
                    np.array([[10.0, 0, 7.5], [0, 10.0, 5.5], [0, 0, 1]], dtype=np.float32),
                    (3, 1, 1),
                ),
                "cam_to_world": np.tile(camera.astype(np.float32), (3, 1, 1)),
            },
            "nerf": {
                "rgb": rng.integers(0, 255, (2, 6, 8, 3), dtype=np.uint8),
                "intrinsics": np.zeros((2, 3, 3), dtype=np.float32),
                "cam_to_world": np.zeros((2, 4, 4), dtype=np.float32),
            },
        }
        return obs, {}

    def render_orthographic(self, roll, pitch, pixel_size=g.PIXEL_SIZE):
        shape = g.image_shape(pixel_size)
        colour = np.zeros((*shape, 3), dtype=np.uint8)
        height = np.zeros(shape, dtype=np.float32)
        action = fake_action(self.seed)
        rotation = g.tilt_matrix(roll, pitch)
        marks = [(action["place"][0], 1)]
        if roll == 0 and pitch == 0:
            marks.append((action["pick"][0], 0))
        for position, channel in marks:
            pixel = np.round(
                g.world_to_pixel(g.world_to_view(position, rotation), pixel_size)
            ).astype(int)
            colour[pixel[0] - 1 : pixel[0] + 2, pixel[1] - 1 : pixel[1] + 2, channel] = MARK
            height[pixel[0], pixel[1]] = 0.05
        return colour, height

    def step(self, action):
        index = self.seed // 2
        return (
            None,
            0.0,
            True,
            False,
            {"success": index % 4 != 1, "failure": None, "position_error": 0.03},
        )


def changed_world(world: dict) -> dict:
    """`world` with its physics and tasks changed."""
    components = {**world["components"], "physics": "0" * 16}
    return {**world, "fingerprint": "0" * 16, "components": components}
