"""Baxter's arms in MuJoCo (thesis 5.2): joint angular velocities as actions, the reach task of reward 5.10.

| module | what it holds |
| --- | --- |
| ``model`` | drrl's own MJCF model: URDF kinematics, limits and masses, capsule links, torso, table |
| ``simulation`` | many MjData stepped one control period at a time on MuJoCo's batch thread pool |
| ``task`` | the reach task: starts, targets, workspace, reward 5.10 and its dense variant, the verdict |
| ``env`` | the native ``BaxterReachVectorEnv`` and the single ``BaxterReachEnv`` |
| ``render`` | headless MuJoCo frames of the scene |

Importing this package registers the environments below with Gymnasium (``gymnasium.make`` gives the single env,
``gymnasium.make_vec`` the native batch); it does not import MuJoCo, which happens when a Baxter env is made. Other
task options (``reward="dense"``, ``action_noise``, ``fixed_target``, ...) are keyword arguments of ``make``.
"""

import gymnasium

ENVIRONMENTS = {
    "drrl/BaxterReach-v0": {"arms": ("right", "left")},  # both arms, the fixed targets, reward 5.10
    "drrl/BaxterReachDense-v0": {"arms": ("right", "left"), "reward": "dense"},
    "drrl/BaxterReachRight-v0": {"arms": ("right",)},  # the thesis's setting: one arm, a fixed target
    "drrl/BaxterReachRightRandom-v0": {"arms": ("right",), "targets": "random"},
}

for _env_id, _options in ENVIRONMENTS.items():
    gymnasium.register(id=_env_id, entry_point="drrl.envs.baxter.env:BaxterReachEnv",
                       vector_entry_point="drrl.envs.baxter.env:BaxterReachVectorEnv", kwargs=dict(_options))
