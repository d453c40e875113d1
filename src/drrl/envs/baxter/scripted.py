"""A scripted stacker: what the stacking task asks, done by hand-written rules through the end-point actions.

Its action is a function of the observation alone, no memory: what it does next is read off the scene. For the
lowest block k not yet on its place:

- not held: the open gripper goes down a funnel over block k (2 cm higher per cm off to the side, at most 10 cm), so
  it arrives from above; at the grip point's place around the block (1.2 cm above the block's centre, as the
  end-point controller keeps the fingertips off the table) it closes;
- held (the gripper closed to less than a third and block k within 2 cm of the grip point's place around it): the
  block goes down a funnel over its place on block k − 1 (at most 8 cm above it), and the gripper opens once the
  block is within 4 mm of its place sideways and 8 mm in height;
- every block placed: the gripper opens and rises 8 cm over the stack.

A gripper that opens stays where it is until it is open (so it never drags a block it lets go of), and the grip
point moves sideways only once it is within 1–4 cm of its aim's height, so that it rises before it carries
anything over the table. The grip point is driven toward its aim at 3 m/s per metre of error, at most 0.3 m/s per
axis. Being memoryless it is a policy a network can copy from its episodes (``drrl.training.cloning``), a reference for
what the task needs, a check that the task can be done, and the source of the starts from demonstrations
(``drrl.envs.baxter.stack_env``). It builds the stack of two in about 6 s and of three in about 10
(tests/test_stacking.py, benchmarks/stacking_scripted.py).
"""

from __future__ import annotations

import numpy as np

from drrl.envs.baxter.grasping import BLOCK_SIZE, CLOSED_WIDTH, OPEN_WIDTH
from drrl.envs.baxter.stacking import StackTask

GAIN = 3.0  # 1/s
SPEED = 0.3  # m/s per axis
GRASP = 0.012  # m: the grip point this far above a grasped block's centre
FUNNEL = 2.0  # m of height over a block (or a place) per m off to its side ...
ABOVE, CLEARANCE = 0.10, 0.08  # ... at most this much over a block to grasp, over a place (and when done)
AT_GRASP = 0.006  # m: close when the grip point is this close to its place around the block
HELD = 0.02  # m: a closed gripper holds the block if the block's grip point is this close to it ...
HELD_OPENING = (BLOCK_SIZE - CLOSED_WIDTH) / (OPEN_WIDTH - CLOSED_WIDTH) + 0.08  # ... and it is this closed or more
OPEN = 0.9  # an opening gripper counts as open from here
AT_PLACE = np.array([0.004, 0.008])  # m: a held block lets go this close to its place, sideways and in height
RISE_FIRST = (0.01, 0.04)  # m below its aim's height at which the grip point starts and stops moving sideways


class ScriptedStacker:
    """The scripted stacker for envs of ``task`` (its controller must be "end_point")."""

    def __init__(self, task: StackTask) -> None:
        if task.controller != "end_point":
            raise ValueError(f"the scripted stacker acts through end-point actions; the task's are {task.controller!r}")
        self.task = task

    def act(self, observations: np.ndarray) -> np.ndarray:
        """Actions (n, 4) for observations (n, observation_size)."""
        task = self.task
        grip, positions = task.observed_grip_point(observations), task.observed_blocks(observations)
        opening = np.asarray(observations[:, 14], dtype=np.float64)
        rows = np.arange(len(observations))
        placed = np.cumprod(task.placed(positions), axis=1).sum(axis=1)  # blocks placed from the bottom up
        done = placed >= task.blocks - 1
        k = np.minimum(placed + 1, task.blocks - 1)
        block, place = positions[rows, k], task.places(positions)[rows, k - 1]
        to_grasp = np.linalg.norm(block + _up(GRASP) - grip, axis=1)
        held = (opening < HELD_OPENING) & (to_grasp < HELD)
        approach = _funnel(block + _up(GRASP), block[:, :2] - grip[:, :2], ABOVE)
        carry = _funnel(place, place[:, :2] - block[:, :2], CLEARANCE) + grip - block  # the block, as it is held
        rise = np.c_[grip[:, :2], np.maximum(grip[:, 2], place[:, 2] + GRASP + CLEARANCE)]
        off_place = np.c_[np.linalg.norm((place - block)[:, :2], axis=1), np.abs(place - block)[:, 2]]
        at_grasp = (to_grasp < AT_GRASP) | ((opening < OPEN) & (to_grasp < 2 * AT_GRASP))  # closing: stay closing
        close = np.where(held, (off_place > AT_PLACE).any(axis=1), at_grasp) & ~done
        aim = np.where(done[:, None], rise, np.where(held[:, None], carry, approach))
        aim = np.where((~close & (opening < OPEN))[:, None], grip, aim)  # opening: wait until open
        error = aim - grip
        velocity = np.clip(GAIN * error, -SPEED, SPEED)
        low, high = RISE_FIRST
        velocity[:, :2] *= np.clip((high - error[:, 2:]) / (high - low), 0.0, 1.0)
        return np.c_[velocity, np.where(close, -1.0, 1.0)].astype(np.float32)


def _funnel(bottom: np.ndarray, sideways: np.ndarray, top: float) -> np.ndarray:
    """Aims (n, 3): ``bottom`` raised by FUNNEL times the ``sideways`` (n, 2) distance, at most ``top``."""
    return bottom + _up(1.0) * np.minimum(FUNNEL * np.linalg.norm(sideways, axis=1), top)[:, None]


def _up(height: float) -> np.ndarray:
    return np.array([0.0, 0.0, height])
