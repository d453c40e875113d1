"""Baxter's forward kinematics in closed form, batched: where each arm's links and gripper end-point are for given
joint angles, from the same URDF numbers as drrl's MJCF model (``drrl.envs.baxter.model``), without MuJoCo.

A world model of Baxter predicts joint angles; the reach task's reward (5.10) and its contact rule then follow from
them through these functions, as the cart-pole's reward follows from its predicted state.

Each joint's frame is its parent's, moved by the URDF origin, turned by the URDF rpy (fixed axes x, y, z) and then
about its own z axis by the joint angle; the hand frame lies ``HAND`` beyond the last joint, the end-point
``END_POINT_OFFSET`` beyond the hand along its z.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from drrl.envs.baxter.model import ARM, END_POINT_OFFSET, HAND, arm_mount

# Points along an arm, as (joint whose frame holds the point, offset in that frame) after that joint: the elbow, the
# wrist, the hand and the end-point. Their capsules' radii are those of the links they sit on.
ARM_POINTS = {"elbow": 3, "wrist": 5, "hand": 6, "end_point": 6}
POINT_RADII = np.array([0.06, 0.05, 0.045, 0.04])  # metres, the links' capsule radii (model.py)


def _rotation_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rotation_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@cache
def _joint_rotations() -> tuple[np.ndarray, ...]:
    """Each joint's fixed rotation from its parent's frame: URDF rpy, fixed axes x then y then z."""
    return tuple(_rotation_z(yaw) @ _rotation_y(pitch) @ _rotation_x(roll) for roll, pitch, yaw in (j.rpy for j in ARM))


def _times(rotations: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """rotations (n, 3, 3) @ matrix (3, m) as one (3n, 3) @ (3, m) product: numpy's batched matmul of tiny
    matrices costs about 4× more."""
    return (rotations.reshape(-1, 3) @ matrix).reshape(len(rotations), 3, -1)


def arm_points(angles: np.ndarray, side: str) -> np.ndarray:
    """Elbow, wrist, hand and end-point (n, 4, 3) in the base frame (metres) for one arm's joint angles (n, 7)."""
    angles = np.asarray(angles, dtype=np.float64)
    n = len(angles)
    mount, yaw = arm_mount(side)
    position = np.broadcast_to(np.asarray(mount, dtype=np.float64), (n, 3)).copy()
    rotation = np.broadcast_to(_rotation_z(yaw), (n, 3, 3)).copy()
    points = np.empty((n, 4, 3))
    cosines, sines = np.cos(angles), np.sin(angles)
    for k, (joint, fixed) in enumerate(zip(ARM, _joint_rotations(), strict=True)):
        position += _times(rotation, np.asarray(joint.origin)[:, None])[:, :, 0]
        rotation = _times(rotation, fixed)
        c, s = cosines[:, k, None], sines[:, k, None]
        x, y = rotation[:, :, 0].copy(), rotation[:, :, 1]
        rotation[:, :, 0] = c * x + s * y  # rotation @ Rz(angle), column by column
        rotation[:, :, 1] = c * y - s * x
        if k == ARM_POINTS["elbow"]:
            points[:, 0] = position
        elif k == ARM_POINTS["wrist"]:
            points[:, 1] = position
    points[:, 2] = position + _times(rotation, np.asarray(HAND)[:, None])[:, :, 0]
    points[:, 3] = points[:, 2] + END_POINT_OFFSET * rotation[:, :, 2]
    return points


def arms_points(angles: np.ndarray, arms: tuple[str, ...]) -> np.ndarray:
    """``arm_points`` of each of ``arms`` (n, arms, 4, 3) for their joint angles side by side (n, 7 · arms)."""
    return np.stack([arm_points(angles[:, 7 * k : 7 * k + 7], side) for k, side in enumerate(arms)], 1)
