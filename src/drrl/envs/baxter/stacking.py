"""The wood-stacking task the thesis announces for Baxter (5.2): put block 1 on block 0 (and block 2 on block 1).

One arm moves (the right by default, as in the thesis's reach) and its gripper; the blocks lie on the table, each a
4 cm pine cube (``drrl.envs.baxter.grasping``). Block 0 stays where it lies; block k must come to rest on block
k − 1. The stack *stands* when every block rests on the one below (centres within 2 cm sideways and 3.5–4.5 cm
above it, block 0 on the table), no finger touches a block and no block moves faster than 2 cm/s; the task is
*done* when the stack has stood for one second, which ends the episode.

Rewards after the transition at 1-based step t ≤ T:

- "thesis", in the form of 5.10: r_t = 0 while the stack stands, −1 otherwise; a failure (an arm or its gripper
  touching the table, the body or the other arm, or a joint at its limit) ends the episode with r_t = −2·(T − t).
  The return counts the steps without a standing stack.
- "dense", staged (beyond the thesis): for the lowest block k not yet on its place, 0.3 for coming near it
  (1 − tanh(10·distance from the grip point)), 0.2 for holding it (both fingers touch it) and, while it is held or
  near its place, 0.5 for bringing it there (1 − tanh(10·distance from its place on block k − 1)); blocks already
  placed count 1 each; r_t is that progress over the B − 1 blocks to place, minus 1 (so in [−1, 0], 0 when the
  stack stands); failures as above.

Actions, per arm: "velocity" (the thesis's), the 7 joint velocities (rad/s) and the gripper's command in [−1, 1]
(−1 closed, 1 open); "end_point" (beyond the thesis, as robot-learning suites offer), the grip point's velocity
(m/s, base frame, at most 0.5 per axis) and the gripper's command, turned into joint velocities through the arm's
Jacobian (damped least squares) while the gripper is held pointing down at the blocks' yaw. Like the operational-space
controllers of robot-learning suites it guards the robot: it stops each joint 0.05 rad inside its limits and the
fingertips 1 cm above the table, so that a policy fails only by hitting something with the arm.

Observations, float32: joint angles (rad), joint velocities as fractions of their limits, the gripper's opening
(1 open, 0 closed), the grip point (m), each block's position (m) and orientation quaternion, each block's offset
from the grip point and each block k ≥ 1's offset from its place on block k − 1 (both in 0.1 m).

Block positions: "fixed" (the thesis's setting: the same every episode), or "random": each block moved uniformly
within ±4 cm and turned within ±0.3 rad of its fixed pose, per episode.

Starts from demonstrations (beyond the thesis, for a curriculum): with ``demo_start`` = f > 0 an episode starts in
the state of one of the scripted stacker's recorded episodes (``drrl.envs.baxter.scripted``) a uniform fraction
between 0 and f of the way through it, e.g. with a block already held. A schedule that shrinks f toward 0 teaches
the end of the task first and the whole of it last (as resets to demonstration states do in robot learning);
measuring always starts from the beginning.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from drrl.envs.baxter.grasping import (
    BLOCK_SIZE,
    BLOCK_TOP_REST,
    FINGER_BASE,
    FINGER_LENGTH,
    GRIP_POINT,
    OPEN_WIDTH,
    PAD_THICKNESS,
)
from drrl.envs.baxter.model import ARM, SIDES, TABLE_TOP, neutral_pose
from drrl.envs.baxter.task import OFFSET_UNIT, START_NOISE, _check_choice, mirror

HORIZON = 2000  # control steps of 0.01 s (as 5.10)
SETTLE_STEPS = 100  # control steps the stack must stand: one second
REWARDS = ("thesis", "dense")
CONTROLLERS = ("velocity", "end_point")
POSITIONS = ("fixed", "random")
# Right-arm coordinates (m, base frame) of the blocks' centres on the table, and their yaw: every one is reached with
# the gripper pointing down (the scripted stacker's tests grip each); the left arm's are mirrored.
FIXED_BLOCKS = ((0.70, -0.35), (0.65, -0.55), (0.62, -0.18))
BLOCK_YAW = np.pi / 4  # the gripper's closing axis at the neutral pose, so a block at rest lies square to the fingers
POSITION_JITTER = 0.04  # m, random positions: ± this in x and y
YAW_JITTER = 0.3  # rad, random positions: ± this
SIDEWAYS = BLOCK_SIZE / 2  # m: a block stands on another if their centres are this close sideways ...
LEVEL_TOLERANCE = 0.005  # ... and its height above the lower one is within this of a block's size
RESTING_SPEED = 0.02  # m/s
MAX_END_POINT_SPEED = 0.5  # m/s per axis (end_point controller)
ORIENTATION_GAIN = 5.0  # 1/s: the end_point controller's correction of the gripper's orientation
NULL_GAIN = 1.0  # 1/s: ... and its pull of the redundant joint motion toward the neutral pose
DAMPING = 0.02  # the damped least squares' λ (m), which keeps joint speeds finite near a singular pose
# The end_point controller's guards: no joint is sent closer than LIMIT_MARGIN to its limits, approached at most at
# LIMIT_GAIN per radian left, and the fingertips not below TIP_CLEARANCE above the table top, approached at most at
# FLOOR_GAIN per metre left (slow enough that the arm's lag does not carry them through).
LIMIT_MARGIN = 0.05  # rad
LIMIT_GAIN = 10.0  # 1/s
TIP_CLEARANCE = 0.01  # m
TIP_BELOW = FINGER_BASE + FINGER_LENGTH - GRIP_POINT  # m: the pads' ends beyond the grip point (2 cm), gripper's z
PAD_SPAN = (OPEN_WIDTH + PAD_THICKNESS) / 2  # m: the pads' centres from the grip point, along its y (open)
PAD_HALF_WIDTH = 0.01  # m, along its x
FLOOR_GAIN = 3.0  # 1/s


@dataclass(frozen=True)
class StackTask:
    """Which arm moves, how many blocks and where, how steps are rewarded and what the actions mean."""

    arms: tuple[str, ...] = ("right",)
    blocks: int = 2
    positions: str = "fixed"
    reward: str = "thesis"
    controller: str = "velocity"
    horizon: int = HORIZON
    start_noise: float = START_NOISE
    demo_start: float = 0.0
    max_velocity: np.ndarray = field(init=False, repr=False)
    joint_low: np.ndarray = field(init=False, repr=False)
    joint_high: np.ndarray = field(init=False, repr=False)
    neutral: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "arms", tuple(self.arms))
        if len(self.arms) != 1 or self.arms[0] not in SIDES:
            raise ValueError(f"stacking moves one arm, ('right',) or ('left',); got arms={self.arms!r}")
        if not 2 <= self.blocks <= len(FIXED_BLOCKS):
            raise ValueError(f"blocks must be 2 or 3 (a stack of two or three), got {self.blocks!r}")
        _check_choice("positions", self.positions, POSITIONS)
        _check_choice("reward", self.reward, REWARDS)
        _check_choice("controller", self.controller, CONTROLLERS)
        if self.horizon <= SETTLE_STEPS or self.start_noise < 0:
            raise ValueError(f"horizon must exceed {SETTLE_STEPS} control steps and start_noise be ≥ 0")
        if not 0.0 <= self.demo_start <= 1.0:
            raise ValueError(f"demo_start must be in [0, 1] (a share of a demonstration), got {self.demo_start!r}")
        object.__setattr__(self, "max_velocity", np.array([j.max_velocity for j in ARM]))
        object.__setattr__(self, "joint_low", np.array([j.lower for j in ARM]))
        object.__setattr__(self, "joint_high", np.array([j.upper for j in ARM]))
        object.__setattr__(self, "neutral", neutral_pose(self.arms[0]))

    @property
    def side(self) -> str:
        return self.arms[0]

    @property
    def num_joints(self) -> int:
        return 7

    @property
    def action_size(self) -> int:
        return (7 if self.controller == "velocity" else 3) + 1

    @property
    def action_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The action Box's (low, high): the joint velocity limits or the end-point speed, then the gripper's ±1."""
        speed = self.max_velocity if self.controller == "velocity" else np.full(3, MAX_END_POINT_SPEED)
        high = np.append(speed, 1.0)
        return -high, high

    @property
    def observation_size(self) -> int:
        return 2 * 7 + 1 + 3 + 7 * self.blocks + 3 * self.blocks + 3 * (self.blocks - 1)

    @property
    def random_numbers_per_start(self) -> int:
        """U[0, 1) numbers one start draws: a noise per joint, then (x, y, yaw) per block if positions are random,
        then with ``demo_start`` a demonstration and a point in it."""
        return 7 + (3 * self.blocks if self.positions == "random" else 0) + (2 if self.demo_start else 0)

    def starts(self, uniform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start joint angles (n, 7) and block poses (n, blocks, 7: position, quaternion) from U[0, 1) numbers."""
        n = len(uniform)
        joints = self.neutral + self.start_noise * (2 * uniform[:, :7] - 1)
        fixed = mirror(np.c_[FIXED_BLOCKS[: self.blocks], np.zeros(self.blocks)], self.side)[:, :2]
        xy = np.broadcast_to(fixed, (n, self.blocks, 2))
        yaw = np.full((n, self.blocks), BLOCK_YAW if self.side == "right" else -BLOCK_YAW)
        if self.positions == "random":
            jitter = 2 * uniform[:, 7 : 7 + 3 * self.blocks].reshape(n, self.blocks, 3) - 1
            xy = xy + POSITION_JITTER * jitter[..., :2]
            yaw = yaw + YAW_JITTER * jitter[..., 2]
        poses = np.zeros((n, self.blocks, 7))
        poses[..., :2], poses[..., 2] = xy, BLOCK_TOP_REST
        poses[..., 3], poses[..., 6] = np.cos(yaw / 2), np.sin(yaw / 2)  # about z
        return joints, poses

    def observe(self, qpos, qvel, openings, grip_points, blocks) -> np.ndarray:
        """Observations (n, observation_size) as the module docstring lists them."""
        n = len(qpos)
        positions = blocks[..., :3]
        to_blocks = (positions - grip_points[:, :1]) / OFFSET_UNIT
        to_places = (positions[:, 1:] - self.places(positions)) / OFFSET_UNIT
        parts = [qpos, qvel / self.max_velocity, openings, grip_points[:, 0], blocks.reshape(n, -1)]
        parts += [to_blocks.reshape(n, -1), to_places.reshape(n, -1)]
        return np.concatenate(parts, axis=1, dtype=np.float32)

    def observed_grip_point(self, observations: np.ndarray) -> np.ndarray:
        """The grip point (n, 3) in observations (n, observation_size)."""
        return np.asarray(observations[:, 15:18], dtype=np.float64)

    def observed_blocks(self, observations: np.ndarray) -> np.ndarray:
        """The blocks' positions (n, blocks, 3) in observations (n, observation_size)."""
        poses = np.asarray(observations[:, 18 : 18 + 7 * self.blocks], dtype=np.float64)
        return poses.reshape(len(observations), self.blocks, 7)[..., :3]

    @staticmethod
    def places(positions: np.ndarray) -> np.ndarray:
        """Where blocks 1, 2, ... belong (n, blocks − 1, 3): on the block below."""
        return positions[:, :-1] + np.array([0.0, 0.0, BLOCK_SIZE])

    def placed(self, positions: np.ndarray) -> np.ndarray:
        """Whether each block k ≥ 1 rests on block k − 1 and block 0 on the table, (n, blocks − 1)."""
        offsets = positions[:, 1:] - self.places(positions)
        on_lower = (np.linalg.norm(offsets[..., :2], axis=2) <= SIDEWAYS) & (np.abs(offsets[..., 2]) <= LEVEL_TOLERANCE)
        on_table = np.abs(positions[:, 0, 2] - BLOCK_TOP_REST) <= LEVEL_TOLERANCE
        return np.asarray(on_lower & on_table[:, None])

    def standing(self, blocks: np.ndarray, touching: np.ndarray, speeds: np.ndarray) -> np.ndarray:
        """Whether the stack stands (n,): every block placed, no finger touching a block, every block at rest."""
        released = ~touching.reshape(len(blocks), -1).any(axis=1)
        return np.asarray(self.placed(blocks[..., :3]).all(axis=1) & released & (speeds <= RESTING_SPEED).all(axis=1))

    def at_limit(self, qpos: np.ndarray) -> np.ndarray:
        """Whether any joint has reached its position limit, (n,)."""
        return np.any((qpos <= self.joint_low) | (qpos >= self.joint_high), axis=1)

    def rewards(self, standing: np.ndarray, progress: np.ndarray, failed: np.ndarray, step: np.ndarray) -> np.ndarray:
        """Each env's reward (n,) after the transition at 1-based ``step`` (see the module docstring)."""
        reward = np.where(standing, 0.0, -1.0 if self.reward == "thesis" else progress - 1.0)
        return np.where(failed, -2.0 * (self.horizon - np.asarray(step)), reward)

    def progress(self, blocks: np.ndarray, touching: np.ndarray, grip_points: np.ndarray) -> np.ndarray:
        """The dense reward's staged progress (n,) in [0, 1]: blocks placed, then the next block's stage."""
        positions = blocks[..., :3]
        n, rows = len(blocks), np.arange(len(blocks))
        placed = self.placed(positions)
        done = np.cumprod(placed, axis=1).sum(axis=1)  # blocks placed from the bottom up
        k = np.minimum(done + 1, self.blocks - 1)  # the block to place next
        block, place = positions[rows, k], self.places(positions)[rows, k - 1]
        near = 1 - np.tanh(10 * np.linalg.norm(block - grip_points[:, 0], axis=1))
        held = touching.reshape(n, 2, self.blocks)[rows, :, k].all(axis=1)
        to_place = np.linalg.norm(block - place, axis=1)
        there = (1 - np.tanh(10 * to_place)) * (held | (to_place < SIDEWAYS))
        stage = 0.3 * near + 0.2 * held + 0.5 * there
        return np.where(done >= self.blocks - 1, 1.0, (done + stage) / (self.blocks - 1))

    def commands(self, actions: np.ndarray, qpos: np.ndarray, jacobians=None) -> tuple[np.ndarray, np.ndarray]:
        """(joint velocities (n, 7) before their limits, gripper openings (n, 1) in [0, 1]) for actions (n,
        action_size); the end_point controller needs ``jacobians`` () -> (J (n, 6, 7), gripper frames (n, 3, 3),
        grip points (n, 3))."""
        openings = (np.clip(actions[:, -1:], -1.0, 1.0) + 1.0) / 2.0
        if self.controller == "velocity":
            return actions[:, :-1], openings
        jacobian, frames, grip_points = jacobians()
        velocity = np.array(actions[:, :3], dtype=np.float64)
        room = fingertip_heights(grip_points, frames) - TIP_CLEARANCE  # (n,) m left above the floor
        velocity[room < 0, :2] = 0.0  # there only up: a move the joint guards cut short may pull it down
        velocity[:, 2] = np.maximum(velocity[:, 2], -FLOOR_GAIN * room)
        error = 0.5 * np.cross(frames, self.gripper_frame(), axis=1).sum(axis=2)  # turns the frame toward the wanted
        twist = np.concatenate([velocity, ORIENTATION_GAIN * error], axis=1)
        transposed = jacobian.transpose(0, 2, 1)  # damped least squares: J^T (J J^T + λ² I)^-1
        inverse = transposed @ np.linalg.inv(jacobian @ transposed + DAMPING**2 * np.eye(6))
        velocities = np.einsum("nij,nj->ni", inverse, twist)
        null = np.eye(7) - np.linalg.pinv(jacobian) @ jacobian  # exact, so the pull does not leak into the twist
        velocities += np.einsum("nij,nj->ni", null, NULL_GAIN * (self.neutral - qpos))
        over = np.abs(velocities / self.max_velocity).max(axis=1, keepdims=True)
        velocities /= np.maximum(over, 1.0)  # within the joints' speed limits, the motion's direction kept
        low, high = self.joint_low + LIMIT_MARGIN - qpos, self.joint_high - LIMIT_MARGIN - qpos
        velocities = np.clip(velocities, LIMIT_GAIN * low, LIMIT_GAIN * high)
        # the guards above bend the motion where a joint stops: slow it as a whole if it then sinks too fast
        sinking = np.einsum("nj,nj->n", jacobian[:, 2], velocities)
        allowed = np.minimum(-FLOOR_GAIN * room, 0.0)
        scale = np.where(sinking < allowed, allowed / np.minimum(sinking, -1e-12), 1.0)
        return velocities * scale[:, None], openings

    def gripper_frame(self) -> np.ndarray:
        """The orientation the end_point controller holds (3, 3), columns the gripper's axes in the base frame: z
        pointing down, the fingers closing along the fixed blocks' yaw."""
        yaw = BLOCK_YAW if self.side == "right" else -BLOCK_YAW
        y, z = np.array([np.cos(yaw), np.sin(yaw), 0.0]), np.array([0.0, 0.0, -1.0])
        return np.stack([np.cross(y, z), y, z], axis=1)


def fingertip_heights(grip_points: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """The lowest fingertip's height above the table top (n,), for grip points (n, 3) and gripper frames (n, 3, 3):
    the pads' ends lie 2 cm beyond the grip point along the gripper's z, 4.1 cm to either side along its y and 1 cm
    along its x."""
    up = frames[:, 2]  # each gripper axis's world z
    lowest = grip_points[:, 2] + TIP_BELOW * up[:, 2] - PAD_SPAN * np.abs(up[:, 1]) - PAD_HALF_WIDTH * np.abs(up[:, 0])
    return lowest - TABLE_TOP


def stacked_fraction(episode_returns: torch.Tensor, terminated: torch.Tensor, horizon: int = HORIZON) -> float:
    """The fraction of episodes that ended with a stack that stood for one second. Under the thesis reward such an
    episode ended early without a penalty, so it returns more than −T, which a failure before its last step cannot."""
    returns, ended = torch.as_tensor(episode_returns), torch.as_tensor(terminated, dtype=torch.bool)
    return float((ended & (returns > -horizon)).double().mean())


def stack_verdict(episode_returns: torch.Tensor, terminated: torch.Tensor) -> dict[str, bool]:
    """For metrics.csv and ``drrl eval`` (thesis reward, full horizon): stacked_80 / stacked_50, at least 80 % / 50 %
    of the episodes built a stack that stood (the bars for fixed / random positions)."""
    fraction = stacked_fraction(episode_returns, terminated)
    return {"stacked_80": fraction >= 0.8, "stacked_50": fraction >= 0.5}


def explain_stack(episode_returns: torch.Tensor, terminated: torch.Tensor) -> str:
    done = round(stacked_fraction(episode_returns, terminated) * terminated.numel())
    return f"({done}/{terminated.numel()} episodes built a stack that stood for one second)"
