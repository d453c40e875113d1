"""Many Baxters stepped together: MuJoCo's batch thread pool (``mujoco.batch``), one control period a call.

Each call runs every simulation for one control period in C threads, with the joint-velocity commands held (the
policy is closed-loop at the control rate), then computes the position and velocity stages at the new state, so that
the end-points and collisions read afterwards belong to the state the policy will observe. One MjData is kept per
simulation (``persistent=True``): the next step starts from those stages instead of computing them again, so they
cost nothing extra (the position stage alone would be computed again by the next step: 10–15 % of the time).
``BaxterBatch`` is a ``drrl.envs.baxter.robot.Robot``: the reach envs step it as they would step real robots.
"""

from __future__ import annotations

import numpy as np

from drrl.envs.baxter.model import SIDES, TIMESTEP, import_mujoco, load_model
from drrl.envs.cores import available_cores


class BaxterBatch:
    """``num_sims`` simulations of Baxter with ``moving_arms`` actuated, advanced ``substeps`` physics steps a call.

    ``qpos``, ``qvel`` and ``targets`` are live (num_sims, ...) views of the simulations' states; ``threads``
    defaults to every available core (at most one per simulation); ``model``, drrl's model of Baxter unless given.
    A stopped simulation (``stop``) is commanded to stand still until it is restarted.
    """

    def __init__(
        self,
        num_sims: int,
        moving_arms: tuple[str, ...] = SIDES,
        substeps: int = 5,
        threads: int | None = None,
        model=None,
    ) -> None:
        mujoco = import_mujoco()
        from mujoco.batch import Batch

        self.arms, self.num_robots = tuple(moving_arms), num_sims
        self.model = load_model(self.arms) if model is None else model
        self.substeps = substeps
        threads = min(threads or available_cores(), num_sims)
        self.stage = mujoco.mjtStage.mjSTAGE_VEL  # kinematics and collisions at the new state, kept for the next step
        self._no_stage = mujoco.mjtStage.mjSTAGE_NONE
        self.batch = Batch(self.model, num_sims, nthread=threads, persistent=True)
        self.qpos = self.batch.bind("qpos")
        self.qvel = self.batch.bind("qvel")
        self._ctrl = self.batch.bind("ctrl")
        self.targets = self.batch.bind("mocap_pos")  # the target markers: drawn, never collided with
        self._site_xpos = self.batch.bind("site_xpos")
        self._ncon = self.batch.bind("ncon")
        self._end_point_sites = [self.model.site(f"{side}_end_point").id for side in moving_arms]
        self._warning_counts = self.batch.warning[:, :, 1]  # (num_sims, kinds): mjWarningStat's "number"
        self._warning_names = [mujoco.mjtWarning(k).name for k in range(self._warning_counts.shape[1])]
        self._stopped = np.zeros(num_sims, dtype=bool)

    @property
    def control_period(self) -> float:
        return self.substeps * TIMESTEP

    @property
    def end_points(self) -> np.ndarray:
        """The gripper end-points (num_sims, arms, 3) at the current state, a fresh array."""
        return self._site_xpos[:, self._end_point_sites]

    @property
    def in_contact(self) -> np.ndarray:
        """Whether anything touches at the current state, (num_sims,). Only failures can touch: an arm with the
        scene or the other arm (see drrl.envs.baxter.model)."""
        return self._ncon > 0

    def restart(self, ids: np.ndarray, qpos: np.ndarray, targets: np.ndarray) -> None:
        """Put simulations ``ids`` at rest at joint angles ``qpos`` (n, joints) with ``targets`` (n, arms, 3)."""
        self.batch.reset(ids, stage=self._no_stage)  # the state is written next
        self.qpos[ids] = qpos
        self.targets[ids] = targets
        self._stopped[ids] = False
        self.batch.forward(ids, stage=self.stage)

    def stop(self, ids: np.ndarray) -> None:
        """The safety stop: simulations ``ids`` are commanded to stand still until restarted."""
        self._stopped[ids] = True

    def step(self, velocities: np.ndarray) -> None:
        """One control period for every simulation with joint-velocity commands ``velocities`` (num_sims, joints)
        held; MuJoCo clamps them to the actuators' ranges.

        Raises RuntimeError if MuJoCo warned in any simulation (e.g. a NaN or diverging state, which MuJoCo would
        otherwise answer by quietly resetting that simulation).
        """
        self._ctrl[:] = velocities
        if self._stopped.any():
            self._ctrl[self._stopped] = 0.0
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
