"""The only module that talks to PyBullet: one physics client per `BulletSim`.

Everything else in the package works through this thin layer, so the rest of
the code never sees client ids, and every call is a single bulk call where
PyBullet offers one (stepping is the hot path of the env).
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator, Sequence

import numpy as np
import pybullet
import pybullet_data

DATA_PATH: str = pybullet_data.getDataPath()


class GuiUnavailable(RuntimeError):
    """The PyBullet GUI cannot open here (no display, or another GUI in this process)."""


class BulletSim:
    """A PyBullet physics client and the operations the Minitaur env needs.

    Args:
        gui: open the PyBullet GUI (``pybullet.GUI``) instead of a headless
            ``DIRECT`` client.
    """

    def __init__(self, gui: bool = False) -> None:
        self._id = -1
        if gui and sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
            raise GuiUnavailable(
                "the PyBullet GUI needs a display and DISPLAY is not set; "
                "use render_mode='rgb_array', or run under xvfb-run"
            )
        self._id = pybullet.connect(pybullet.GUI if gui else pybullet.DIRECT)
        if self._id < 0:
            raise GuiUnavailable(
                "could not open the PyBullet GUI (PyBullet allows one GUI per process)"
                if gui
                else "could not connect to PyBullet"
            )
        self.gui = gui
        if gui:
            pybullet.configureDebugVisualizer(pybullet.COV_ENABLE_GUI, 0, physicsClientId=self._id)

    # -- lifetime -----------------------------------------------------------
    def close(self) -> None:
        """Disconnect the client; calling it again does nothing."""
        if self._id >= 0:
            if pybullet.isConnected(physicsClientId=self._id):
                pybullet.disconnect(physicsClientId=self._id)
            self._id = -1

    def __del__(self) -> None:
        # At interpreter shutdown the pybullet module may be gone already.
        with contextlib.suppress(Exception):
            self.close()

    # -- world --------------------------------------------------------------
    @contextlib.contextmanager
    def rendering_paused(self) -> Iterator[None]:
        """In the GUI, draw nothing while the world is (re)built, as the classic env does:
        the window otherwise redraws as each body loads (seconds a URDF under a software
        OpenGL such as Xvfb's). Headless, it changes nothing."""
        if not self.gui:
            yield
            return
        pybullet.configureDebugVisualizer(
            pybullet.COV_ENABLE_RENDERING, 0, physicsClientId=self._id
        )
        try:
            yield
        finally:
            pybullet.configureDebugVisualizer(
                pybullet.COV_ENABLE_RENDERING, 1, physicsClientId=self._id
            )

    def reset_world(self, time_step: float, solver_iterations: int, gravity: float) -> None:
        """Empty the world and set the physics parameters (the classic order)."""
        cid = self._id
        pybullet.resetSimulation(physicsClientId=cid)
        pybullet.setPhysicsEngineParameter(
            numSolverIterations=int(solver_iterations), physicsClientId=cid
        )
        pybullet.setTimeStep(time_step, physicsClientId=cid)
        pybullet.setGravity(0, 0, gravity, physicsClientId=cid)

    def load_plane(self) -> int:
        plane = self.load_urdf("plane.urdf")
        pybullet.changeVisualShape(plane, -1, rgbaColor=[1, 1, 1, 0.9], physicsClientId=self._id)
        pybullet.configureDebugVisualizer(
            pybullet.COV_ENABLE_PLANAR_REFLECTION, 0, physicsClientId=self._id
        )
        return plane

    def load_urdf(
        self,
        file_name: str,
        position: Sequence[float] = (0.0, 0.0, 0.0),
        orientation: Sequence[float] = (0.0, 0.0, 0.0, 1.0),
        self_collision: bool = False,
        urdf_root: str = DATA_PATH,
    ) -> int:
        flags = pybullet.URDF_USE_SELF_COLLISION if self_collision else 0
        return pybullet.loadURDF(
            f"{urdf_root}/{file_name}",
            list(position),
            list(orientation),
            flags=flags,
            physicsClientId=self._id,
        )

    def step(self) -> None:
        pybullet.stepSimulation(physicsClientId=self._id)

    def sort_contact_pairs(self) -> None:
        """Process contact pairs in a canonical order from now on.

        By default Bullet solves contacts in the order their pairs were found, which
        depends on everything simulated since the world was built; a restored state
        then evolves differently after every episode. Sorting the pairs makes a
        restored state evolve the same way every time (but in a different order
        from the classic env, which never sorts).
        """
        pybullet.setPhysicsEngineParameter(
            deterministicOverlappingPairs=1, physicsClientId=self._id
        )

    def save_state(self) -> int:
        return pybullet.saveState(physicsClientId=self._id)

    def restore_state(self, state_id: int) -> None:
        pybullet.restoreState(stateId=state_id, physicsClientId=self._id)

    # -- bodies and joints ----------------------------------------------------
    def joint_names(self, body: int) -> list[tuple[str, str]]:
        """(joint name, child link name) for every joint, in index order."""
        cid = self._id
        infos = (
            pybullet.getJointInfo(body, i, physicsClientId=cid)
            for i in range(pybullet.getNumJoints(body, physicsClientId=cid))
        )
        return [(info[1].decode(), info[12].decode()) for info in infos]

    def mass(self, body: int, link: int) -> float:
        return pybullet.getDynamicsInfo(body, link, physicsClientId=self._id)[0]

    def set_mass(self, body: int, link: int, mass: float) -> None:
        pybullet.changeDynamics(body, link, mass=mass, physicsClientId=self._id)

    def inertia(self, body: int, link: int) -> tuple[float, float, float]:
        """The link's local inertia diagonal (kg m^2)."""
        return tuple(pybullet.getDynamicsInfo(body, link, physicsClientId=self._id)[2])

    def set_inertia(self, body: int, link: int, diagonal: Sequence[float]) -> None:
        pybullet.changeDynamics(
            body, link, localInertiaDiagonal=list(diagonal), physicsClientId=self._id
        )

    def set_lateral_friction(self, body: int, link: int, friction: float) -> None:
        pybullet.changeDynamics(body, link, lateralFriction=friction, physicsClientId=self._id)

    def reset_joint(self, body: int, joint: int, angle: float) -> None:
        pybullet.resetJointState(body, joint, angle, targetVelocity=0, physicsClientId=self._id)

    def reset_base(
        self, body: int, position: Sequence[float], orientation: Sequence[float]
    ) -> None:
        cid = self._id
        pybullet.resetBasePositionAndOrientation(body, position, orientation, physicsClientId=cid)
        pybullet.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=cid)

    def add_point_constraint(
        self,
        body: int,
        link_a: int,
        link_b: int,
        pivot_a: Sequence[float],
        pivot_b: Sequence[float],
    ) -> int:
        return pybullet.createConstraint(
            body,
            link_a,
            body,
            link_b,
            pybullet.JOINT_POINT2POINT,
            [0, 0, 0],
            list(pivot_a),
            list(pivot_b),
            physicsClientId=self._id,
        )

    def fix_base_in_air(self, body: int, height: float) -> None:
        pybullet.createConstraint(
            body,
            -1,
            -1,
            -1,
            pybullet.JOINT_FIXED,
            [0, 0, 0],
            [0, 0, 0],
            [0, 0, height],
            physicsClientId=self._id,
        )

    def free_joints(self, body: int, joints: Sequence[int]) -> None:
        """Switch off PyBullet's built-in velocity motors so torques drive the joints."""
        self.set_joint_friction(body, joints, [0.0] * len(joints))

    def set_joint_friction(
        self, body: int, joints: Sequence[int], frictions: Sequence[float]
    ) -> None:
        """Coulomb friction on free joints: a velocity motor with target 0 and this force."""
        pybullet.setJointMotorControlArray(
            body,
            list(joints),
            pybullet.VELOCITY_CONTROL,
            targetVelocities=[0.0] * len(joints),
            forces=list(frictions),
            physicsClientId=self._id,
        )

    def apply_base_force(self, body: int, force: Sequence[float]) -> None:
        """Push the base's centre of mass with a world-frame force for the next step."""
        position, _ = self.base_pose(body)
        pybullet.applyExternalForce(
            body, -1, list(force), list(position), pybullet.WORLD_FRAME, physicsClientId=self._id
        )

    def base_angular_velocity(self, body: int) -> np.ndarray:
        """The base's angular velocity in the world frame (rad/s)."""
        return np.array(pybullet.getBaseVelocity(body, physicsClientId=self._id)[1])

    def set_torques(self, body: int, joints: Sequence[int], torques: Sequence[float]) -> None:
        pybullet.setJointMotorControlArray(
            body, joints, pybullet.TORQUE_CONTROL, forces=torques, physicsClientId=self._id
        )

    def set_position_targets(
        self,
        body: int,
        joints: Sequence[int],
        targets: Sequence[float],
        kp: float,
        kd: float,
        max_force: float,
    ) -> None:
        n = len(joints)
        pybullet.setJointMotorControlArray(
            body,
            joints,
            pybullet.POSITION_CONTROL,
            targetPositions=targets,
            positionGains=[kp] * n,
            velocityGains=[kd] * n,
            forces=[max_force] * n,
            physicsClientId=self._id,
        )

    def joint_positions_velocities(
        self, body: int, joints: Sequence[int]
    ) -> tuple[np.ndarray, np.ndarray]:
        states = pybullet.getJointStates(body, joints, physicsClientId=self._id)
        return (
            np.array([s[0] for s in states]),
            np.array([s[1] for s in states]),
        )

    def joint_torques(self, body: int, joints: Sequence[int]) -> np.ndarray:
        states = pybullet.getJointStates(body, joints, physicsClientId=self._id)
        return np.array([s[3] for s in states])

    def base_pose(self, body: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(position xyz, orientation quaternion xyzw) of the body's base."""
        return pybullet.getBasePositionAndOrientation(body, physicsClientId=self._id)

    def contact_points(self, body: int, other: int) -> list[tuple[int, np.ndarray]]:
        """(link of ``body``, world position on ``body``) of each contact with ``other``."""
        return [
            (point[3], np.array(point[5]))
            for point in pybullet.getContactPoints(body, other, physicsClientId=self._id)
        ]

    def point_velocity(self, body: int, link: int, point: np.ndarray) -> np.ndarray:
        """World velocity (m/s) of the material point of ``link`` now at ``point``."""
        if link == -1:
            linear, angular = pybullet.getBaseVelocity(body, physicsClientId=self._id)
            centre, _ = self.base_pose(body)
        else:
            state = pybullet.getLinkState(
                body, link, computeLinkVelocity=1, physicsClientId=self._id
            )
            centre, linear, angular = state[0], state[6], state[7]
        return np.array(linear) + np.cross(angular, point - np.array(centre))

    def has_contact(self, body_a: int, body_b: int) -> bool:
        return len(pybullet.getContactPoints(body_a, body_b, physicsClientId=self._id)) > 0

    @staticmethod
    def up_axis_z(orientation: Sequence[float]) -> float:
        """World-z component of the body's local up axis (1 upright, -1 upside down)."""
        x, y, _, _ = orientation
        # Third row, third column of the rotation matrix of a unit quaternion.
        return 1.0 - 2.0 * (x * x + y * y)

    # -- camera -------------------------------------------------------------
    def render(
        self,
        target: Sequence[float],
        width: int,
        height: int,
        distance: float,
        yaw: float,
        pitch: float,
        fov: float = 60.0,
    ) -> np.ndarray:
        """An RGB uint8 frame (height, width, 3) from CPU TinyRenderer."""
        cid = self._id
        view = pybullet.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=list(target),
            distance=distance,
            yaw=yaw,
            pitch=pitch,
            roll=0,
            upAxisIndex=2,
            physicsClientId=cid,
        )
        projection = pybullet.computeProjectionMatrixFOV(
            fov=fov, aspect=width / height, nearVal=0.1, farVal=100.0, physicsClientId=cid
        )
        _, _, rgba, _, _ = pybullet.getCameraImage(
            width=width,
            height=height,
            viewMatrix=view,
            projectionMatrix=projection,
            renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK,
            physicsClientId=cid,
        )
        frame = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        return np.ascontiguousarray(frame[:, :, :3])

    def follow_with_gui_camera(
        self, target: Sequence[float], distance: float, yaw: float, pitch: float
    ) -> None:
        pybullet.resetDebugVisualizerCamera(
            distance, yaw, pitch, list(target), physicsClientId=self._id
        )
