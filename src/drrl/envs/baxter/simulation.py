"""Many Baxters stepped together: MuJoCo's batch thread pool (``mujoco.batch``), one control period a call.

Each call runs every simulation for one control period in C threads, with the joint-velocity commands held (the
policy is closed-loop at the control rate), then computes the position and velocity stages at the new state, so that
the end-points and collisions read afterwards belong to the state the policy will observe. One MjData is kept per
simulation (``persistent=True``): the next step starts from those stages instead of computing them again, so they
cost nothing extra (the position stage alone would be computed again by the next step: 10–15 % of the time).
``BaxterBatch`` is a ``drrl.envs.baxter.robot.Robot``: the reach envs step it as they would step real robots. With
``blocks`` given it simulates the grasping scene instead (``drrl.envs.baxter.grasping``: grippers, blocks, failures
read from contact sensors), and also reads the grippers' openings, the blocks' poses and what the fingers touch.
"""

from __future__ import annotations

import numpy as np

from drrl.envs.baxter.grasping import FAILURE_SENSORS, FINGER_TRAVEL, load_grasping_model
from drrl.envs.baxter.model import ARM, SIDES, TIMESTEP, import_mujoco, load_model
from drrl.envs.cores import available_cores


class BaxterBatch:
    """``num_sims`` simulations of Baxter with ``moving_arms`` actuated, advanced ``substeps`` physics steps a call.

    ``qpos`` and ``qvel`` (the arms' joints) and ``targets`` are live (num_sims, ...) views of the simulations'
    states (``qpos`` and ``qvel`` copies where the grippers' joints sit between two arms'); ``threads`` defaults to
    every available core (at most one per simulation); ``model``, drrl's model of Baxter (or with ``blocks``, of the
    grasping scene) unless given. A stopped simulation (``stop``) is commanded to stand still until it is restarted;
    its grippers keep their last command.
    """

    def __init__(
        self,
        num_sims: int,
        moving_arms: tuple[str, ...] = SIDES,
        substeps: int = 5,
        threads: int | None = None,
        model=None,
        blocks: int | None = None,
    ) -> None:
        mujoco = import_mujoco()
        from mujoco.batch import Batch

        self.arms, self.num_robots = tuple(moving_arms), num_sims
        if model is None:
            model = load_model(self.arms) if blocks is None else load_grasping_model(self.arms, blocks)
        self.model, self.grasping = model, blocks is not None
        self.substeps = substeps
        threads = min(threads or available_cores(), num_sims)
        self.stage = mujoco.mjtStage.mjSTAGE_VEL  # kinematics and collisions at the new state, kept for the next step
        self._no_stage = mujoco.mjtStage.mjSTAGE_NONE
        self.batch = Batch(self.model, num_sims, nthread=threads, persistent=True)
        joints = [self.model.joint(f"{side}_{joint}") for side in self.arms for joint in (j.name for j in ARM)]
        self.dofs = np.array([self.model.jnt_dofadr[joint.id] for joint in joints])  # the arms' joints' dof columns
        self._q = _columns([self.model.jnt_qposadr[joint.id] for joint in joints])
        self._v = _columns(self.dofs.tolist())
        self.num_joints = len(joints)
        self._qpos, self._qvel = self.batch.bind("qpos"), self.batch.bind("qvel")
        self._ctrl = self.batch.bind("ctrl")
        self.targets = self.batch.bind("mocap_pos")  # the target markers: drawn, never collided with
        self._site_xpos = self.batch.bind("site_xpos")
        self._ncon = self.batch.bind("ncon")
        self._sensors = self.batch.bind("sensordata")
        self._site_xmat = self.batch.bind("site_xmat")
        self._end_point_sites = [self.model.site(f"{side}_end_point").id for side in moving_arms]
        if self.grasping:
            self._grip_sites = [self.model.site(f"{side}_grip").id for side in moving_arms]
            fingers = [self.model.joint(f"{side}_finger{k}").id for side in self.arms for k in (1, 2)]
            self._fingers = self.model.jnt_qposadr[fingers].reshape(len(self.arms), 2)
            self.num_blocks = int(blocks or 0)
            self._block_q = self.model.jnt_qposadr[[self.model.joint(f"block{k}").id for k in range(self.num_blocks)]]
            self._block_v = self.model.jnt_dofadr[[self.model.joint(f"block{k}").id for k in range(self.num_blocks)]]
        self._warning_counts = self.batch.warning[:, :, 1]  # (num_sims, kinds): mjWarningStat's "number"
        self._warning_names = [mujoco.mjtWarning(k).name for k in range(self._warning_counts.shape[1])]
        self._stopped = np.zeros(num_sims, dtype=bool)

    @property
    def control_period(self) -> float:
        return self.substeps * TIMESTEP

    @property
    def qpos(self) -> np.ndarray:
        """The arms' joint angles (num_sims, joints), rad."""
        return self._qpos[:, self._q]

    @property
    def qvel(self) -> np.ndarray:
        """The arms' joint velocities (num_sims, joints), rad/s."""
        return self._qvel[:, self._v]

    @property
    def end_points(self) -> np.ndarray:
        """The gripper end-points (num_sims, arms, 3) at the current state, a fresh array."""
        return self._site_xpos[:, self._end_point_sites]

    @property
    def in_contact(self) -> np.ndarray:
        """Whether a failure touches at the current state, (num_sims,): an arm with the scene or the other arm. In
        the reach scene nothing else can touch (see drrl.envs.baxter.model); in the grasping scene the contact
        sensors tell failures from touching blocks."""
        if self.grasping:
            return self._sensors[:, :FAILURE_SENSORS].any(axis=1)
        return self._ncon > 0

    @property
    def grip_points(self) -> np.ndarray:
        """Grasping scene: the point between the fingers where a grasped block's centre sits (num_sims, arms, 3)."""
        return self._site_xpos[:, self._grip_sites]

    @property
    def grip_frames(self) -> np.ndarray:
        """Grasping scene: each gripper's axes as the columns of a rotation (num_sims, arms, 3, 3), base frame."""
        return self._site_xmat[:, self._grip_sites].reshape(self.num_robots, len(self.arms), 3, 3)

    @property
    def openings(self) -> np.ndarray:
        """Grasping scene: each gripper's opening (num_sims, arms), 1 open, 0 closed (the fingers' mean travel)."""
        return 1.0 - self._qpos[:, self._fingers].mean(axis=2) / FINGER_TRAVEL

    @property
    def blocks(self) -> np.ndarray:
        """Grasping scene: each block's position and orientation quaternion (num_sims, blocks, 7)."""
        return self._qpos[:, self._block_q[:, None] + np.arange(7)]

    @property
    def block_speeds(self) -> np.ndarray:
        """Grasping scene: each block's linear speed (num_sims, blocks), m/s."""
        return np.linalg.norm(self._qvel[:, self._block_v[:, None] + np.arange(3)], axis=2)

    @property
    def touching(self) -> np.ndarray:
        """Grasping scene: whether finger f of arm a touches block k, (num_sims, arms, 2, blocks)."""
        shape = (self.num_robots, len(self.arms), 2, self.num_blocks)  # the order of the scene's sensors
        found = self._sensors[:, FAILURE_SENSORS : FAILURE_SENSORS + np.prod(shape[1:])] > 0
        return found.reshape(shape)

    def restart(self, ids: np.ndarray, qpos: np.ndarray, targets: np.ndarray, blocks: np.ndarray | None = None) -> None:
        """Put simulations ``ids`` at rest at joint angles ``qpos`` (n, joints) with ``targets`` (n, arms, 3); in the
        grasping scene, the grippers open and the blocks at ``blocks`` (n, blocks, 7: position, quaternion)."""
        self.batch.reset(ids, stage=self._no_stage)  # the state is written next
        _write(self._qpos, ids, self._q, qpos)
        self.targets[ids] = targets
        if self.grasping:
            self._ctrl[ids, self.num_joints :] = 1.0
            if self.num_blocks:
                self._qpos[ids[:, None, None], self._block_q[:, None] + np.arange(7)] = blocks
        self._stopped[ids] = False
        self.batch.forward(ids, stage=self.stage)

    def states(self) -> np.ndarray:
        """Every simulation's whole state (num_sims, nq + nv + nu): positions, velocities, commands; a fresh array."""
        return np.concatenate([self._qpos, self._qvel, self._ctrl], axis=1)

    def restore(self, ids: np.ndarray, states: np.ndarray) -> None:
        """Put simulations ``ids`` in ``states`` (n, nq + nv + nu), as ``states`` gave them, and restart them."""
        nq, nv = self._qpos.shape[1], self._qvel.shape[1]
        self._qpos[ids], self._qvel[ids], self._ctrl[ids] = (
            states[:, :nq],
            states[:, nq : nq + nv],
            states[:, nq + nv :],
        )
        self._stopped[ids] = False
        self.batch.forward(ids, stage=self.stage)

    def stop(self, ids: np.ndarray) -> None:
        """The safety stop: simulations ``ids`` are commanded to stand still until restarted."""
        self._stopped[ids] = True

    def step(self, velocities: np.ndarray, openings: np.ndarray | None = None) -> None:
        """One control period for every simulation with joint-velocity commands ``velocities`` (num_sims, joints)
        held, and in the grasping scene the grippers' opening commands ``openings`` (num_sims, arms) in [0, 1]
        (None: as before); MuJoCo clamps them to the actuators' ranges.

        Raises RuntimeError if MuJoCo warned in any simulation (e.g. a NaN or diverging state, which MuJoCo would
        otherwise answer by quietly resetting that simulation).
        """
        self._ctrl[:, : self.num_joints] = velocities
        if openings is not None:
            self._ctrl[:, self.num_joints :] = openings
        if self._stopped.any():
            self._ctrl[self._stopped, : self.num_joints] = 0.0
        self.batch.step(nstep=self.substeps, stage=self.stage)
        if self._warning_counts.any():
            sims, kinds = np.nonzero(self._warning_counts)
            names = sorted({self._warning_names[k] for k in kinds})
            raise RuntimeError(
                f"MuJoCo warned ({', '.join(names)}) in simulation(s) {sorted(set(sims.tolist()))}: "
                f"their physics is no longer valid"
            )

    def data(self, sim: int = 0):
        """Simulation ``sim`` as a ``mujoco.MjData`` (a copy), e.g. to render it."""
        return self.batch.get_data(sim)


def _columns(addresses: list[int]) -> slice | np.ndarray:
    """State columns as a slice where they are contiguous (numpy then gives views), else as an index array."""
    first = addresses[0] if addresses else 0
    if list(addresses) == list(range(first, first + len(addresses))):
        return slice(first, first + len(addresses))
    return np.asarray(addresses)


def _write(array: np.ndarray, rows: np.ndarray, columns: slice | np.ndarray, values: np.ndarray) -> None:
    if isinstance(columns, slice):
        array[rows, columns] = values
    else:
        array[np.ix_(rows, columns)] = values
