"""The PyBullet scene of one swarm landing: floor, drones, and the plate with its pads and stand.

Everything lives in one PyBullet client of its own (``DIRECT`` by default, ``GUI`` on request);
every call passes ``physicsClientId``, so any number of worlds coexist in one process.

Bodies:

* **floor**: an infinite collision plane at ``z = 0`` (and a grey slab to look at).
* **drones**: one :data:`CF2X_URDF` each, loaded with its inertia from the file.
* **platform**: ONE multibody without mass (PyBullet treats it as immovable), whose base is
  the acrylic plate and whose fixed links are the pads (link ``i`` is drone ``i``'s pad) and,
  for the UR10 kinds, a column standing for the arm that holds the plate. Contact points name
  the link they touch, which is how the simulator tells a drone's own pad from anything else.
  Moving platforms are moved kinematically, by setting their pose at every control tick (48 Hz)
  from :class:`~marlander_lite.platforms.PlatformMotion` (at 0.5 m/s a 1 cm step, sideways).

The plate's and pads' *collision* shapes reach 3 cm below their top faces (the plate looks
5 mm thick): a drone at the 3 m/s speed limit moves 12.5 mm per 240 Hz step, and must not pass
through a thin slab between two collision checks.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pybullet as p
from scipy.spatial.transform import Rotation

from marlander_lite.crazyflie.params import GRAVITY, CF2XParams, PhysicsConfig
from marlander_lite.platforms import PlatformConfig

CF2X_URDF: Path = Path(str(resources.files("marlander_lite") / "assets" / "cf2x.urdf"))
"""Our Crazyflie 2.x model (see the comment at its top)."""
COLLISION_DEPTH = 0.03
"""How far the plate's and pads' collision shapes reach below their top faces (m)."""
STAND_RADIUS = 0.075
"""Radius of the column that stands for the UR10 holding the plate (m): the UR10's wrist is about 0.15 m wide."""
PAD_COLOURS = ((0.9, 0.2, 0.2, 1.0), (0.2, 0.4, 0.9, 1.0), (0.2, 0.7, 0.3, 1.0), (0.9, 0.7, 0.1, 1.0))
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def connect(gui: bool) -> int:
    """Open a PyBullet client: ``GUI`` (one per process, needs a display) or headless ``DIRECT``."""
    if (
        gui
        and sys.platform.startswith("linux")
        and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    ):
        # PyBullet's GUI exits the whole process when it finds no X server: refuse before that.
        raise RuntimeError(
            "gui=True / render_mode='human' needs a display, and DISPLAY is not set; run headless "
            "(gui=False) and use render_mode='rgb_array' or video_path to see the flight."
        )
    client = p.connect(p.GUI if gui else p.DIRECT)
    if client < 0:
        raise RuntimeError("PyBullet could not open a GUI window; use gui=False (headless) or check the display.")
    if gui:
        p.configureDebugVisualizer(p.COV_ENABLE_GUI, 0, physicsClientId=client)
    return client


class World:
    """Builds and owns the bodies of one scene; see the module docstring.

    Args:
        client: a PyBullet client id from :func:`connect`.
        num_drones: N.
        platform: which plate motion; decides whether the UR10 column is built.
        params: the drone model; its mass and inertia override the URDF's.
        physics: the physics time step.
        arena_half_width: half the arena side (m), for the floor slab.
    """

    def __init__(
        self,
        client: int,
        num_drones: int,
        platform: PlatformConfig,
        params: CF2XParams,
        physics: PhysicsConfig,
        arena_half_width: float,
    ) -> None:
        self.client = cid = client
        self.params = params
        p.resetSimulation(physicsClientId=cid)
        p.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=cid)
        # One stepSimulation call advances one control period in physics_hz / control_hz steps.
        p.setPhysicsEngineParameter(
            fixedTimeStep=1.0 / physics.control_hz,
            numSubSteps=physics.steps_per_tick,
            deterministicOverlappingPairs=1,
            physicsClientId=cid,
        )
        self.floor = self._build_floor(arena_half_width)
        flags = p.URDF_USE_INERTIA_FROM_FILE | p.URDF_USE_IMPLICIT_CYLINDER
        self.drones: list[int] = []
        for i in range(num_drones):
            body = p.loadURDF(str(CF2X_URDF), [3.0 * i, 0.0, 1.0], flags=flags, physicsClientId=cid)
            # Our own drag model replaces PyBullet's default velocity damping.
            p.changeDynamics(body, -1, linearDamping=0.0, angularDamping=0.0, physicsClientId=cid)
            self.drones.append(body)
            self.set_drone_mass(i, latched=False)
        self.platform, self.pad_links = self._build_platform(num_drones, platform)
        self._platform_links = list(range(-1, p.getNumJoints(self.platform, physicsClientId=cid)))
        # The plate, pads and column never move against the floor: skip those contact pairs.
        for link in self._platform_links:
            p.setCollisionFilterPair(self.platform, self.floor, link, -1, 0, physicsClientId=cid)
        self.drone_index = {body: i for i, body in enumerate(self.drones)}

    # ------------------------------------------------------------------ construction
    def _build_floor(self, half_width: float) -> int:
        cid = self.client
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
        slab = p.createVisualShape(
            p.GEOM_BOX,
            halfExtents=[half_width + 0.5, half_width + 0.5, 0.001],
            visualFramePosition=[0, 0, -0.001],
            rgbaColor=[0.55, 0.55, 0.58, 1.0],
            physicsClientId=cid,
        )
        return p.createMultiBody(0.0, plane, slab, physicsClientId=cid)

    def _build_platform(self, num_drones: int, platform: PlatformConfig) -> tuple[int, list[int]]:
        cid = self.client
        geometry = platform.geometry
        # Beyond the paper: an inclined plate is the level one turned by geometry.rotation() about its top-face
        # centre. The links are laid out level, in the plate's own frame; the base orientation tilts them all
        # (the UR10 column too: the arm holds the plate at that angle).
        self.plate_orientation = tuple(Rotation.from_matrix(geometry.rotation()).as_quat().tolist())
        """The plate's orientation, PyBullet's (x, y, z, w); identity unless the plate is inclined."""
        if geometry.inclination_deg:
            geometry = dataclasses.replace(geometry, inclination_deg=0.0)
        hx, hy = geometry.half_extents(num_drones)
        plate_col = p.createCollisionShape(
            p.GEOM_BOX,
            halfExtents=[hx, hy, COLLISION_DEPTH / 2],
            collisionFramePosition=[0, 0, -COLLISION_DEPTH / 2],
            physicsClientId=cid,
        )
        plate_vis = p.createVisualShape(
            p.GEOM_BOX,
            halfExtents=[hx, hy, geometry.plate_thickness / 2],
            visualFramePosition=[0, 0, -geometry.plate_thickness / 2],
            rgbaColor=[0.85, 0.9, 0.95, 0.9],
            physicsClientId=cid,
        )
        cols, viss, positions = [], [], []
        pad_height = geometry.pad_thickness + COLLISION_DEPTH
        for i, offset in enumerate(geometry.pad_offsets(num_drones)):
            cols.append(
                p.createCollisionShape(
                    p.GEOM_CYLINDER,
                    radius=geometry.pad_radius,
                    height=pad_height,
                    collisionFramePosition=[0, 0, -pad_height / 2],
                    physicsClientId=cid,
                )
            )
            viss.append(
                p.createVisualShape(
                    p.GEOM_CYLINDER,
                    radius=geometry.pad_radius,
                    length=geometry.pad_thickness,
                    visualFramePosition=[0, 0, -geometry.pad_thickness / 2],
                    rgbaColor=PAD_COLOURS[i % len(PAD_COLOURS)],
                    physicsClientId=cid,
                )
            )
            positions.append(offset.tolist())
        if platform.kind != "static-floor":
            # A column from below the floor up to the plate's underside, whatever the plate's height.
            length = platform.elevated_height[1] + 0.1
            centre = -geometry.plate_thickness - length / 2
            cols.append(
                p.createCollisionShape(p.GEOM_CYLINDER, radius=STAND_RADIUS, height=length, physicsClientId=cid)
            )
            viss.append(
                p.createVisualShape(
                    p.GEOM_CYLINDER,
                    radius=STAND_RADIUS,
                    length=length,
                    rgbaColor=[0.3, 0.5, 0.75, 1.0],
                    physicsClientId=cid,
                )
            )
            positions.append([0.0, 0.0, centre])
        count = len(cols)
        body = p.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=plate_col,
            baseVisualShapeIndex=plate_vis,
            basePosition=[0.0, 0.0, geometry.plate_thickness],
            baseOrientation=list(self.plate_orientation),
            linkMasses=[0.0] * count,
            linkCollisionShapeIndices=cols,
            linkVisualShapeIndices=viss,
            linkPositions=positions,
            linkOrientations=[IDENTITY] * count,
            linkInertialFramePositions=[[0.0, 0.0, 0.0]] * count,
            linkInertialFrameOrientations=[IDENTITY] * count,
            linkParentIndices=[0] * count,
            linkJointTypes=[p.JOINT_FIXED] * count,
            linkJointAxis=[[0.0, 0.0, 1.0]] * count,
            physicsClientId=cid,
        )
        return body, list(range(num_drones))

    # ------------------------------------------------------------------ per-step helpers
    def set_drone_mass(self, i: int, latched: bool) -> None:
        """Give drone ``i`` its mass and inertia from :class:`CF2XParams`, or none (``latched``: immovable).

        A latched drone also stops colliding with the platform it rests on (both are then
        immovable, and their contact would only cost time); other drones still hit it.
        """
        cid = self.client
        for link in getattr(self, "_platform_links", []):
            p.setCollisionFilterPair(self.drones[i], self.platform, -1, link, int(not latched), physicsClientId=cid)
        if latched:
            p.changeDynamics(self.drones[i], -1, mass=0.0, physicsClientId=cid)
        else:
            inertia = self.params.inertia.tolist()
            p.changeDynamics(
                self.drones[i], -1, mass=self.params.mass, localInertiaDiagonal=inertia, physicsClientId=self.client
            )

    def place_drone(
        self, i: int, pos: np.ndarray, quat: tuple[float, ...] = IDENTITY, keep_velocity: bool = False
    ) -> None:
        """Put drone ``i`` at ``pos`` (m) with attitude ``quat`` (x, y, z, w), at rest unless ``keep_velocity``."""
        cid = self.client
        p.resetBasePositionAndOrientation(self.drones[i], list(pos), quat, physicsClientId=cid)
        if not keep_velocity:
            p.resetBaseVelocity(self.drones[i], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=cid)

    def move_platform(self, plate_pos: list[float]) -> None:
        """Set the plate's top-face centre to ``plate_pos`` (m), level or at its inclination."""
        p.resetBasePositionAndOrientation(self.platform, plate_pos, self.plate_orientation, physicsClientId=self.client)

    def render(self, width: int, height: int, target: tuple[float, float, float], distance: float) -> np.ndarray:
        """An RGB image ``(height, width, 3)`` uint8 from a camera looking at ``target`` (m) from ``distance``."""
        cid = self.client
        view = p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=list(target),
            distance=distance,
            yaw=30.0,
            pitch=-30.0,
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=cid,
        )
        proj = p.computeProjectionMatrixFOV(
            fov=60.0, aspect=width / height, nearVal=0.05, farVal=30.0, physicsClientId=cid
        )
        _, _, rgba, _, _ = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=cid)
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[..., :3].copy()
