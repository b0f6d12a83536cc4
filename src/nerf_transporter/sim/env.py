"""RavensEnv: a gymnasium environment of one task, one pick-and-place per step.

PyBullet's C extension prints its build time when imported and its arguments when it connects,
straight to the process's standard output and error; `native_output_silenced` keeps both out of the
output of every command (and the GUI's start-up chatter out of standard output).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import math
import os
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from nerf_transporter import geometry
from nerf_transporter.sim import assets, cameras
from nerf_transporter.sim.primitives import pick_and_place
from nerf_transporter.sim.robot import Robot
from nerf_transporter.sim.tasks import TASKS
from nerf_transporter.sim.tasks.base import SETTINGS, Task


@contextlib.contextmanager
def native_output_silenced(stderr: bool = True) -> Iterator[None]:
    """Point file descriptor 1 (and 2 unless `stderr` is False) at the null device meanwhile.

    This silences what native code writes to the process's descriptors, past `sys.stdout` and
    `sys.stderr`; Python's streams are flushed before and C's stdio buffers before the descriptors
    are restored, so nothing else is lost or reordered.
    """
    descriptors = (1, 2) if stderr else (1,)
    for stream in (sys.stdout, sys.stderr):
        if stream is not None:
            stream.flush()
    saved = [os.dup(fd) for fd in descriptors]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in descriptors:
            os.dup2(null, fd)
        yield
    finally:
        if os.name == "posix":
            ctypes.CDLL(None).fflush(None)
        for fd, copy in zip(descriptors, saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)
        os.close(null)


with native_output_silenced():
    import pybullet
    from pybullet_utils.bullet_client import BulletClient

RIGS = ("state", "rgbd", "nerf")
TIME_STEP = 1.0 / 480.0  # the anchor's simulation rate
TABLE_FRICTION = 1.0  # the anchor's ground plane
SETTLED_SPEED = 0.005  # m/s: the scene has settled when every movable body is slower
SETTLE_LIMIT = 5.0  # s of simulated time at most (the anchor's motion timeout)
TABLE_SIZE = (1.6, 1.6, 0.02)
VIDEO_EYE = np.array([0.55, -1.25, 0.75])
VIDEO_TARGET = np.array([0.35, 0.0, 0.15])
VIDEO_CAMERA = cameras.Camera(
    cameras.intrinsics_matrix(300.0, (360, 480)),
    cameras.look_at(VIDEO_EYE, VIDEO_TARGET),
    (360, 480),
)
HIDDEN_POSITION = (0.0, 0.0, -50.0)
RENDER_MODES = ("human", "rgb_array")


def connect(render_mode: str | None = None) -> BulletClient:
    """A new PyBullet client: headless, or PyBullet's GUI window for `render_mode="human"`.

    The GUI looks at the workspace from where `VIDEO_CAMERA` does. Without a display PyBullet's GUI
    would end the process, so a missing `DISPLAY` (Linux) is a RuntimeError here instead.
    """
    if render_mode != "human":
        with native_output_silenced():
            return BulletClient(connection_mode=pybullet.DIRECT)
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        raise RuntimeError(
            "render_mode='human' opens PyBullet's GUI window, which needs a display (DISPLAY is "
            "not set); render_mode='rgb_array' returns frames without one"
        )
    offset = VIDEO_EYE - VIDEO_TARGET
    distance = geometry.norm(offset)
    with native_output_silenced(stderr=False):
        client = BulletClient(connection_mode=pybullet.GUI)
        client.configureDebugVisualizer(pybullet.COV_ENABLE_GUI, 0)
        client.resetDebugVisualizerCamera(
            cameraDistance=distance,
            cameraYaw=math.degrees(math.atan2(offset[0], -offset[1])),
            cameraPitch=-math.degrees(math.asin(offset[2] / distance)),
            cameraTargetPosition=VIDEO_TARGET.tolist(),
        )
    return client


def checked_action(action: object) -> tuple[geometry.Pose, geometry.Pose]:
    """(pick, place) of a `step` action, each (position [3], quaternion [4]) as float arrays;
    ValueError naming what is wrong otherwise (not a mapping, a pose missing or wrongly shaped).
    Non-finite values pass: the motion fails on them, as on any pose the robot cannot reach."""
    if not isinstance(action, Mapping) or not {"pick", "place"} <= set(action):
        raise ValueError(
            "an action is {'pick': pose, 'place': pose}, each pose (position [3], quaternion "
            f"[4]); got {action!r:.80}"
        )
    poses = []
    for key in ("pick", "place"):
        try:
            position, quaternion = (np.asarray(part, dtype=float) for part in action[key])
        except (TypeError, ValueError) as error:
            raise ValueError(
                f"action[{key!r}] must be (position [3], quaternion [4]), got {action[key]!r:.80}"
            ) from error
        if (position.size, quaternion.size) != (3, 4):
            raise ValueError(
                f"action[{key!r}] must be (position [3], quaternion [4]), got shapes "
                f"{position.shape} and {quaternion.shape}"
            )
        poses.append((position.reshape(3), quaternion.reshape(4)))
    return poses[0], poses[1]


def _pose_space() -> spaces.Tuple:
    position = spaces.Box(
        low=geometry.BOUNDS[:, 0].astype(np.float32), high=geometry.BOUNDS[:, 1].astype(np.float32)
    )
    return spaces.Tuple((position, spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)))


def _camera_space(count: int, size: tuple[int, int], depth: bool) -> spaces.Dict:
    height, width = size
    entries = {
        "rgb": spaces.Box(0, 255, shape=(count, height, width, 3), dtype=np.uint8),
        "intrinsics": spaces.Box(-np.inf, np.inf, shape=(count, 3, 3), dtype=np.float32),
        "cam_to_world": spaces.Box(-np.inf, np.inf, shape=(count, 4, 4), dtype=np.float32),
    }
    if depth:
        entries["depth"] = spaces.Box(0.0, np.inf, shape=(count, height, width), dtype=np.float32)
    return spaces.Dict(entries)


class RavensEnv(gym.Env):
    """UR5e + suction in PyBullet with one task; `step` executes one pick-and-place.

    `rigs` picks what `obs` holds (`state`, `rgbd`, `nerf`; see docs/interfaces.md). Episodes are
    functions of the reset seed. The `nerf` rig is captured with the arm out of view (as if it had
    moved away for the capture) unless `nerf_show_robot`; the `rgbd` rig sees the arm at home.
    The `nerf` rig is `cameras.nerf_cameras(nerf_views, nerf_image_size)` unless `nerf_cameras`
    names other cameras (a rig under study; `nerf_views` and `nerf_image_size` then stay at their
    defaults, the count and size being the cameras' own).

    `render_mode`: `"rgb_array"` makes `render()` return a frame of a fixed side camera; `"human"`
    shows the simulation in PyBullet's GUI window (needs a display) and runs it no faster than
    real time, so that the motion can be followed.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 24}

    def __init__(
        self,
        task: Task,
        rigs: Sequence[str] = ("state",),
        nerf_views: int = 30,
        nerf_image_size: tuple[int, int] = cameras.IMAGE_SIZE,
        render_mode: str | None = None,
        nerf_show_robot: bool = False,
        nerf_cameras: Sequence[cameras.Camera] | None = None,
    ) -> None:
        unknown = [rig for rig in rigs if rig not in RIGS]
        if unknown:
            raise ValueError(f"unknown rig(s) {unknown}; valid rigs: {', '.join(RIGS)}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"unknown render_mode {render_mode!r}; valid: {', '.join(RENDER_MODES)}"
            )
        self.task = task
        self.rigs = tuple(rigs)
        self.render_mode = render_mode
        self.nerf_show_robot = nerf_show_robot
        if nerf_cameras is not None:
            if (nerf_views, tuple(nerf_image_size)) != (30, cameras.IMAGE_SIZE):
                raise ValueError(
                    "nerf_views and nerf_image_size are for the default nerf rig; with nerf_cameras "
                    "leave them out (the count and size are the cameras' own)"
                )
            if not nerf_cameras:
                raise ValueError("nerf_cameras must hold at least one camera")
            if len({camera.image_size for camera in nerf_cameras}) > 1:
                raise ValueError("the nerf_cameras must share one image size")
            nerf_views, nerf_image_size = len(nerf_cameras), nerf_cameras[0].image_size
        if "nerf" not in rigs:
            self.nerf_cameras = []
        elif nerf_cameras is not None:
            self.nerf_cameras = list(nerf_cameras)
        else:
            self.nerf_cameras = cameras.nerf_cameras(nerf_views, tuple(nerf_image_size))
        self.rgbd_cameras = cameras.rgbd_cameras() if "rgbd" in rigs else []
        observation = {}
        if "state" in rigs:
            observation["state"] = spaces.Box(
                -np.inf, np.inf, shape=(task.state_dim(),), dtype=np.float32
            )
        if "rgbd" in rigs:
            observation["rgbd"] = _camera_space(3, self.rgbd_cameras[0].image_size, depth=True)
        if "nerf" in rigs:
            observation["nerf"] = _camera_space(nerf_views, tuple(nerf_image_size), depth=False)
        self.observation_space = spaces.Dict(observation)
        self.action_space = spaces.Dict({"pick": _pose_space(), "place": _pose_space()})
        self.client = connect(render_mode)
        self.robot: Robot | None = None
        self.frame_callback: Callable[[np.ndarray], None] | None = None
        self.frame_every = 8
        self._sim_steps = 0
        self._steps = 0
        self._clock = (time.perf_counter(), 0)  # (wall-clock time, simulation steps) of a start

    # -- gymnasium API -------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        client = self.client
        client.resetSimulation()
        client.setGravity(0, 0, -9.8)
        client.setTimeStep(TIME_STEP)
        table = assets.write_urdf(
            "table",
            [assets.Box(TABLE_SIZE)],
            color=assets.COLORS["table"],
            mass=0.0,
            friction=TABLE_FRICTION,
        )
        self.table_id = assets.load(
            client,
            table,
            (np.array([0.5, 0.0, -TABLE_SIZE[2] / 2]), np.array([0, 0, 0, 1.0])),
            fixed=True,
        )
        self.robot = Robot(client)
        self._sim_steps = 0
        self._steps = 0
        self._clock = (time.perf_counter(), 0)
        self.task.reset(self, self.np_random)
        self.settle()
        return self._observation(), {"seed": seed}

    def step(self, action: dict) -> tuple[dict, float, bool, bool, dict]:
        if not self.client.isConnected():
            raise RuntimeError("step() after close(): make a new environment")
        if self.robot is None:
            raise RuntimeError("call reset() before step()")
        pick, place = checked_action(action)
        self._clock = (time.perf_counter(), self._sim_steps)
        failure = pick_and_place(self, pick, place)
        self.settle()
        self._steps += 1
        reward, info = self.task.reward(self)
        if failure is not None:  # the anchor's timeout: a failed motion scores 0 whatever the pose
            reward, info["success"], info["strict_success"] = 0.0, False, False
        # The task is over when solved or when its pick-and-places are used up (one for these tasks).
        terminated = bool(info["success"]) or self._steps >= self.task.max_steps
        info["failure"] = failure
        return self._observation(), reward, terminated, False, info

    def render(self) -> np.ndarray | None:
        """RGB frame of a fixed side camera that sees the robot and the workspace (`rgb_array`);
        None otherwise (`human`: the GUI window shows the simulation as it runs)."""
        if self.render_mode != "rgb_array":
            return None
        return cameras.render(self.client, VIDEO_CAMERA)[0]

    def close(self) -> None:
        if self.client is not None and self.client.isConnected():
            with native_output_silenced(stderr=False):  # the GUI reports its threads stopping
                self.client.disconnect()

    # -- simulation ------------------------------------------------------------------------------

    def step_simulation(self, count: int = 1) -> None:
        """Advance physics; every `frame_every` steps hand a video frame to `frame_callback`.
        In render mode `human`, wait as needed so that simulated time does not run ahead of the
        wall clock since the last `reset` or `step` began."""
        for _ in range(count):
            self.client.stepSimulation()
            self._sim_steps += 1
            if self.frame_callback is not None and self._sim_steps % self.frame_every == 0:
                self.frame_callback(cameras.render(self.client, VIDEO_CAMERA)[0])
            if self.render_mode == "human":
                start_time, start_steps = self._clock
                ahead = start_time + (self._sim_steps - start_steps) * TIME_STEP
                time.sleep(max(0.0, ahead - time.perf_counter()))

    def is_dynamic(self, body: int) -> bool:
        return (
            body not in (self.robot.id, self.table_id)
            and self.client.getDynamicsInfo(body, -1)[0] > 0
        )

    def settle(self) -> None:
        """Step until every movable body's linear speed is below `SETTLED_SPEED` (the anchor's
        `is_static`, checked before every step), or for `SETTLE_LIMIT` seconds at most."""
        bodies = [self.client.getBodyUniqueId(k) for k in range(self.client.getNumBodies())]
        movable = [body for body in bodies if self.is_dynamic(body)]
        for _ in range(int(round(SETTLE_LIMIT / TIME_STEP))):
            speeds = [self.client.getBaseVelocity(body)[0] for body in movable]
            if all(geometry.norm(v) < SETTLED_SPEED for v in speeds):
                return
            self.step_simulation()

    # -- observations ----------------------------------------------------------------------------

    def _observation(self) -> dict:
        return {rig: self.capture(rig) for rig in self.rigs}

    def capture(self, rig: str):
        """The observation of one rig (chosen at construction) in the current state."""
        if rig not in self.rigs:
            raise ValueError(f"rig {rig!r} was not chosen at construction; chosen: {self.rigs}")
        if rig == "state":
            return self.task.state(self)
        if rig == "rgbd":
            return cameras.capture(self.client, self.rgbd_cameras, depth=True)
        nerf = functools.partial(cameras.capture, self.client, self.nerf_cameras)
        return nerf() if self.nerf_show_robot else self._without_robot(nerf)

    def _without_robot(self, render: Callable[[], tuple]) -> tuple:
        self.client.resetBasePositionAndOrientation(self.robot.id, HIDDEN_POSITION, (0, 0, 0, 1))
        try:
            return render()
        finally:
            self.client.resetBasePositionAndOrientation(self.robot.id, (0, 0, 0), (0, 0, 0, 1))

    def render_orthographic(
        self, roll: float, pitch: float, pixel_size: float = geometry.PIXEL_SIZE
    ) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth colour and height of view (roll, pitch), robot not shown (docs/conventions.md,
        "Views and the view grid")."""
        return self._without_robot(
            lambda: cameras.render_orthographic(self.client, roll, pitch, pixel_size)
        )

    def render_segmentation_top_down(self) -> tuple[np.ndarray, np.ndarray]:
        """Body ids [H, W] and height [H, W] of the top-down view, robot not shown."""
        _, height, ids = self._without_robot(
            lambda: cameras.render_orthographic(self.client, 0.0, 0.0, segmentation=True)
        )
        return ids, height


def make_env(
    task: str,
    setting: str = "normal",
    *,
    rigs: Sequence[str] = ("state",),
    nerf_views: int = 30,
    nerf_image_size: tuple[int, int] = cameras.IMAGE_SIZE,
    render_mode: str | None = None,
    nerf_show_robot: bool = False,
    nerf_cameras: Sequence[cameras.Camera] | None = None,
) -> RavensEnv:
    """A `RavensEnv` for `task` in `setting`; unknown names raise ValueError listing valid ones."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; valid tasks: {', '.join(sorted(TASKS))}")
    if setting not in SETTINGS:
        raise ValueError(f"unknown setting {setting!r}; valid settings: {', '.join(SETTINGS)}")
    return RavensEnv(
        TASKS[task](setting),
        rigs,
        nerf_views,
        nerf_image_size,
        render_mode,
        nerf_show_robot,
        nerf_cameras,
    )
