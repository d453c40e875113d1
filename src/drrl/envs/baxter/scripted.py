"""A scripted stacker: what the stacking task asks, done by hand-written rules through the end-point actions.

For k = 1, 2, ...: bring the open gripper 10 cm above block k, lower it around the block (the grip point 1.2 cm
above the block's centre, as the end-point controller keeps the fingertips off the table), close it (0.7 s), lift to
8 cm above the stack, move over block k − 1, put block k down on it, open (0.5 s) and rise again. Each stage ends
when the grip point is within 5 mm of its aim (or its time has passed); the grip point is driven toward its aim at
3 m/s per metre of error, at most 0.3 m/s per axis. It reads only the observations, so it is a policy (with a
stage per env as its memory): a reference for what the task needs, a check that the task can be done, and a
source of demonstrations. It builds the stack of two in about 7 s and of three in about 14 (tests/test_stacking.py).
"""

from __future__ import annotations

import numpy as np

from drrl.envs.baxter.grasping import BLOCK_SIZE
from drrl.envs.baxter.stacking import StackTask

GAIN = 3.0  # 1/s
SPEED = 0.3  # m/s per axis
ARRIVED = 0.005  # m
ABOVE = 0.10  # m over a block before going down to it
GRASP = 0.012  # m: the grip point this far above a grasped block's centre (the controller keeps the fingers 1 cm
#                off the table)
CLEARANCE = BLOCK_SIZE + 0.08  # m over the lower block while carrying
CLOSE_STEPS, OPEN_STEPS = 70, 50  # control steps to close around a block, and to let it go
STAGES = 8


class ScriptedStacker:
    """The scripted stacker for ``num_envs`` envs of ``task`` (its controller must be "end_point")."""

    def __init__(self, task: StackTask, num_envs: int) -> None:
        if task.controller != "end_point":
            raise ValueError(f"the scripted stacker acts through end-point actions; the task's are {task.controller!r}")
        self.task, self.num_envs = task, num_envs
        self.stage, self.timer = np.zeros(num_envs, dtype=np.int64), np.zeros(num_envs, dtype=np.int64)
        self.block = np.ones(num_envs, dtype=np.int64)  # the block to place

    def reset(self, envs: np.ndarray) -> None:
        """Start over in the envs where ``envs`` (num_envs,) is True (their episodes restarted)."""
        self.stage[envs], self.timer[envs], self.block[envs] = 0, 0, 1

    def act(self, observations: np.ndarray) -> np.ndarray:
        """Actions (num_envs, 4) for observations (num_envs, observation_size); advances each env's stage."""
        grip, positions = self.task.observed_grip_point(observations), self.task.observed_blocks(observations)
        rows = np.arange(self.num_envs)
        block, lower = positions[rows, self.block], positions[rows, self.block - 1]
        carry = lower[:, 2:] + CLEARANCE
        aims = np.stack(
            [
                block + _up(ABOVE),  # 0: above the block
                block + _up(GRASP),  # 1: around it
                grip,  # 2: close
                np.c_[grip[:, :2], carry],  # 3: lift
                lower + _up(CLEARANCE),  # 4: above the lower block
                lower + _up(BLOCK_SIZE + GRASP + 0.002),  # 5: put it down
                grip,  # 6: let go
                np.c_[grip[:, :2], carry],  # 7: rise
            ],
            axis=1,
        )
        stage = np.minimum(self.stage, STAGES - 1)
        error = aims[rows, stage] - grip
        closed = (stage >= 2) & (stage <= 5)
        actions = np.c_[np.clip(GAIN * error, -SPEED, SPEED), np.where(closed, -1.0, 1.0)]
        self._advance(np.linalg.norm(error, axis=1) < ARRIVED)
        return actions

    def _advance(self, arrived: np.ndarray) -> None:
        self.timer += 1
        waited = np.where(self.stage == 2, self.timer > CLOSE_STEPS, self.timer > OPEN_STEPS)
        done = np.where(np.isin(self.stage, (2, 6)), waited, arrived) & (self.timer > 5)
        self.stage = np.where(done, self.stage + 1, self.stage)
        self.timer = np.where(done, 0, self.timer)
        next_block = (self.stage == STAGES) & (self.block < self.task.blocks - 1)
        self.block = np.where(next_block, self.block + 1, self.block)
        self.stage = np.where(next_block, 0, self.stage)


def _up(height: float) -> np.ndarray:
    return np.array([0.0, 0.0, height])
