"""Camera rigs and rendering: the RGB-D trio, the NeRF ring, and ground-truth orthographic views.

Cameras follow OpenCV: x right, y down, z forward; intrinsics in pixels with the centre of pixel
(row v, column u) at (u, v). All renders use PyBullet's CPU renderer with one fixed world light,
so a surface has the same colour from every camera (what a radiance field assumes).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from nerf_transporter import geometry

LIGHT = {
    "lightDirection": [0.3, -0.4, 1.0],
    "lightColor": [1.0, 1.0, 1.0],
    "lightAmbientCoeff": 0.6,
    "lightDiffuseCoeff": 0.4,
    "lightSpecularCoeff": 0.0,
    "shadow": 0,
}
# The orthographic eye sits this far above the box: PyBullet's depth conversion then stays valid
# (its implied perspective near/far planes, see render_orthographic, enclose the whole box).
ORTHO_EYE_OFFSET = 1.5
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
NERF_RADIUS = 1.05  # m from the workspace centre
NERF_ELEVATION = (math.radians(35.0), math.radians(75.0))
RGBD_EYES = ((1.0, 0.0, 0.75), (0.0, 0.5, 0.75), (0.0, -0.5, 0.75))
RGBD_TARGETS = ((0.25, 0.0, 0.0), (0.55, -0.05, 0.0), (0.55, 0.05, 0.0))


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: 3x3 intrinsics, 4x4 OpenCV camera-to-world pose, (height, width)."""

    intrinsics: np.ndarray
    cam_to_world: np.ndarray
    image_size: tuple[int, int]
    near: float = 0.01
    far: float = 10.0


def intrinsics_matrix(focal: float, image_size: tuple[int, int]) -> np.ndarray:
    height, width = image_size
    return np.array(
        [[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]]
    )


def look_at(
    eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0, 0, 1)
) -> np.ndarray:
    """OpenCV camera-to-world pose of a camera at `eye` looking at `target`, image up along `up`."""
    eye, target = np.asarray(eye, dtype=float), np.asarray(target, dtype=float)
    forward = target - eye
    forward /= geometry.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=float))
    if geometry.norm(right) < 1e-9:
        raise ValueError("look_at: the viewing direction is parallel to `up`")
    right /= geometry.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, forward, eye
    return pose


IMAGE_SIZE = (480, 640)  # (rows, cols) of the RGB-D and NeRF cameras


def rgbd_cameras(image_size: tuple[int, int] = IMAGE_SIZE, focal: float = 450.0) -> list[Camera]:
    """The three RealSense-like cameras of Ravens: front, left and right, 0.75 m high."""
    intrinsics = intrinsics_matrix(focal, image_size)
    return [
        Camera(intrinsics, look_at(eye, target), image_size)
        for eye, target in zip(RGBD_EYES, RGBD_TARGETS, strict=True)
    ]


def nerf_cameras(
    count: int = 30, image_size: tuple[int, int] = IMAGE_SIZE, focal: float = 450.0
) -> list[Camera]:
    """`count` cameras on a spiral around the workspace centre (one turn, elevation rising from 35
    to 75 degrees), each looking at the centre; `focal` is for 480 x 640 and scales with the width."""
    if count < 1:
        raise ValueError(f"the nerf rig needs at least one camera, got {count}")
    focal = focal * image_size[1] / 640
    intrinsics = intrinsics_matrix(focal, image_size)
    cameras = []
    for k in range(count):
        azimuth = 2 * math.pi * k / count
        elevation = NERF_ELEVATION[0] + (NERF_ELEVATION[1] - NERF_ELEVATION[0]) * k / max(
            count - 1, 1
        )
        direction = np.array(
            [
                math.cos(elevation) * math.cos(azimuth),
                math.cos(elevation) * math.sin(azimuth),
                math.sin(elevation),
            ]
        )
        eye = geometry.WORKSPACE_CENTER + NERF_RADIUS * direction
        cameras.append(Camera(intrinsics, look_at(eye, geometry.WORKSPACE_CENTER), image_size))
    return cameras


def _projection(camera: Camera) -> np.ndarray:
    """OpenGL projection reproducing the pinhole intrinsics (pixel centres at integer u, v).

    PyBullet's CPU renderer samples pixels at integer window coordinates counted from the bottom
    left, so OpenCV's column u is window x = u and row v is window y = H - 1 - v."""
    height, width = camera.image_size
    fx, fy = camera.intrinsics[0, 0], camera.intrinsics[1, 1]
    cx, cy = camera.intrinsics[0, 2], camera.intrinsics[1, 2] + 1.0
    near, far = camera.near, camera.far
    return np.array(
        [
            [2 * fx / width, 0.0, 1 - 2 * cx / width, 0.0],
            [0.0, 2 * fy / height, 2 * cy / height - 1, 0.0],
            [0.0, 0.0, -(far + near) / (far - near), -2 * far * near / (far - near)],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )


def _gl(matrix: np.ndarray) -> list[float]:
    """Column-major flattening expected by PyBullet."""
    return [float(v) for v in np.asarray(matrix).T.ravel()]


def render(client, camera: Camera, depth: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """RGB uint8 [H, W, 3] and, if asked, depth in metres along the optical axis [H, W]."""
    height, width = camera.image_size
    view = geometry.matmul(OPENGL_FROM_OPENCV, geometry.invert_transform(camera.cam_to_world))
    _, _, rgba, depth_buffer, _ = client.getCameraImage(
        width,
        height,
        viewMatrix=_gl(view),
        projectionMatrix=_gl(_projection(camera)),
        renderer=client.ER_TINY_RENDERER,
        flags=client.ER_NO_SEGMENTATION_MASK,
        **LIGHT,
    )
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3]
    if not depth:
        return rgb, None
    buffer = np.asarray(depth_buffer, dtype=np.float32).reshape(height, width)
    near, far = camera.near, camera.far
    metres = far * near / (far - (far - near) * buffer)
    return rgb, metres.astype(np.float32)


def capture(client, cameras: Sequence[Camera], depth: bool = False) -> dict[str, np.ndarray]:
    """Render every camera of a rig into the observation dict of docs/interfaces.md."""
    images = [render(client, camera, depth) for camera in cameras]
    result = {
        "rgb": np.stack([rgb for rgb, _ in images]),
        "intrinsics": np.stack([c.intrinsics for c in cameras]).astype(np.float32),
        "cam_to_world": np.stack([c.cam_to_world for c in cameras]).astype(np.float32),
    }
    if depth:
        result["depth"] = np.stack([d for _, d in images])
    return result


def render_orthographic(
    client,
    roll: float,
    pitch: float,
    pixel_size: float = geometry.PIXEL_SIZE,
    segmentation: bool = False,
) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground-truth orthographic view (roll, pitch) of everything in the client
    (docs/conventions.md, "Views and the view grid").

    Pixel (i, j) shows the first surface met from above along the view axis at view coordinates
    x' = 0.25 + j s, y' = -0.5 + i s; height is that surface's z'. Returns colour uint8 [H, W, 3]
    and height float32 [H, W] (plus body ids [H, W], -1 for none, with `segmentation`). Hide the
    robot before calling (the environment does). A camera looking down sees the Ravens image
    mirrored, so columns are flipped after rendering.
    """
    rows, cols = geometry.image_shape(pixel_size)
    rotation = geometry.tilt_matrix(roll, pitch)
    corners = np.array(
        [
            [x, y, z]
            for x in geometry.BOUNDS[0]
            for y in geometry.BOUNDS[1]
            for z in geometry.BOUNDS[2]
        ]
    )
    heights = geometry.world_to_view(corners, rotation)[:, 2]
    top, bottom = heights.max() + 0.05, heights.min() - 0.3
    centre_x = (geometry.BOUNDS[0, 0] + geometry.BOUNDS[0, 1]) / 2
    eye = geometry.view_to_world(np.array([centre_x, 0.0, top + ORTHO_EYE_OFFSET]), rotation)
    # Camera frame (OpenGL): x right = -x', y up = -y', looking along -z'.
    camera_to_world = np.eye(4)
    camera_to_world[:3, :3] = geometry.matmul(rotation, np.diag([-1.0, -1.0, 1.0]))
    camera_to_world[:3, 3] = eye
    view = geometry.invert_transform(camera_to_world)
    # Pixels are sampled at integer window coordinates from the bottom left (see _projection):
    # column k (before the flip) at x' = x0 + (cols - 1 - k) s, row m at y' = y0 + m s.
    left = centre_x - geometry.BOUNDS[0, 0] - (cols - 1) * pixel_size
    right = left + cols * pixel_size
    top_edge = -geometry.BOUNDS[1, 0] + pixel_size
    bottom_edge = top_edge - rows * pixel_size
    near, far = ORTHO_EYE_OFFSET, ORTHO_EYE_OFFSET + top - bottom
    projection = np.array(
        [
            [2 / (right - left), 0, 0, -(right + left) / (right - left)],
            [
                0,
                2 / (top_edge - bottom_edge),
                0,
                -(top_edge + bottom_edge) / (top_edge - bottom_edge),
            ],
            [0, 0, -2 / (far - near), -(far + near) / (far - near)],
            [0, 0, 0, 1.0],
        ]
    )
    flags = 0 if segmentation else client.ER_NO_SEGMENTATION_MASK
    _, _, rgba, depth_buffer, seg = client.getCameraImage(
        cols,
        rows,
        viewMatrix=_gl(view),
        projectionMatrix=_gl(projection),
        renderer=client.ER_TINY_RENDERER,
        flags=flags,
        **LIGHT,
    )
    colour = np.asarray(rgba, dtype=np.uint8).reshape(rows, cols, 4)[:, ::-1, :3]
    # The renderer stores depth as if the projection were perspective, with near and far planes read
    # off the matrix; invert that map (exact for any projection) to get the distance along the axis.
    buffer = np.asarray(depth_buffer, dtype=np.float64).reshape(rows, cols)[:, ::-1]
    near_p = projection[2, 3] / (projection[2, 2] - 1)
    far_p = projection[2, 3] / (projection[2, 2] + 1)
    distance = far_p * near_p / (far_p - buffer * (far_p - near_p))
    height = np.where(buffer < 1.0, top + ORTHO_EYE_OFFSET - distance, bottom).astype(np.float32)
    colour = np.ascontiguousarray(colour)
    if not segmentation:
        return colour, np.ascontiguousarray(height)
    ids = np.asarray(seg, dtype=np.int64).reshape(rows, cols)[:, ::-1]
    ids = np.where(ids >= 0, ids & ((1 << 24) - 1), -1)
    return colour, np.ascontiguousarray(height), np.ascontiguousarray(ids)
