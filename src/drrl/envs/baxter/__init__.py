"""Baxter's arms in MuJoCo (thesis 5.2): joint angular velocities as actions, the reach task of reward 5.10, and
the wood stacking the thesis announces, with Baxter's grippers.

| module | what it holds |
| --- | --- |
| ``model`` | drrl's own MJCF model: URDF kinematics, limits and masses, capsule links, torso, table |
| ``simulation`` | many MjData stepped one control period at a time on MuJoCo's batch thread pool |
| ``task`` | the reach task: starts, targets, workspace, reward 5.10 and its dense variant, the verdict |
| ``native`` | what the native envs share: seeding, next-step autoreset, frames, the single env over a batch of one |
| ``env`` | the native ``BaxterReachVectorEnv`` and the single ``BaxterReachEnv`` |
| ``grasping`` | the stacking scene: Rethink's electric grippers on the hands, pine blocks, contact sensors |
| ``stacking`` | the stacking task: block positions, stack rule, rewards in 5.10's form and staged, the controllers |
| ``stack_env`` | the native ``BaxterStackVectorEnv`` and the single ``BaxterStackEnv`` |
| ``scripted`` | the scripted stacker, rules on the observation: the end-point tasks' demonstrator (for cloning) |
| ``standin`` | a stand-in for the real robot: masses and damping off, delayed and lagging commands, noisy sensors |
| ``render`` | headless MuJoCo frames of the scene |

Importing this package registers the environments below with Gymnasium (``gymnasium.make`` gives the single env,
``gymnasium.make_vec`` the native batch); it does not import MuJoCo, which happens when a Baxter env is made. Other
task options (``controller``, ``reward``, ``action_noise``, ``fixed_target``, ...) are keyword arguments of ``make``.
"""

from functools import partial
from typing import Any

from drrl.envs.baxter.model import SIDES
from drrl.envs.baxter.scripted import ScriptedStacker
from drrl.envs.baxter.stacking import StackTask, explain_stack, stack_verdict
from drrl.envs.baxter.task import STILLNESS, TIE_BREAK, ReachTask, explain_reach, reach_verdict
from drrl.envs.registry import EnvEntry, register

ENVIRONMENTS: dict[
    str, tuple[str, dict[str, Any], bool]
] = {  # alias, Gymnasium id, task options, whether the verdict of reward 5.10 applies
    "baxter-reach": ("drrl/BaxterReach-v0", {"arms": ("right", "left")}, True),  # both arms, fixed targets
    "baxter-reach-dense": ("drrl/BaxterReachDense-v0", {"arms": ("right", "left"), "reward": "dense"}, False),
    "baxter-reach-right": ("drrl/BaxterReachRight-v0", {"arms": ("right",)}, True),  # the thesis's setting
    "baxter-reach-right-random": ("drrl/BaxterReachRightRandom-v0", {"arms": ("right",), "targets": "random"}, True),
    # the thesis's setting on a stand-in for the real robot (``standin``): physics off, delay, lag, noisy sensors
    "baxter-reach-right-standin": ("drrl/BaxterReachRightStandIn-v0", {"arms": ("right",), "stand_in": {}}, True),
    # through the joint-target controller (``task``'s docstring says why)
    "baxter-reach-right-targets": (
        "drrl/BaxterReachRightTargets-v0",
        {"arms": ("right",), "controller": "joint_targets"},
        True,
    ),
    "baxter-reach-targets": ("drrl/BaxterReachTargets-v0", {"arms": SIDES, "controller": "joint_targets"}, True),
    "baxter-reach-dense-targets": (
        "drrl/BaxterReachDenseTargets-v0",
        {"arms": SIDES, "reward": "dense", "controller": "joint_targets"},
        False,
    ),
}


for _alias, (_env_id, _options, _thesis_reward) in ENVIRONMENTS.items():
    _judged: dict[str, Any] = {"verdict": reach_verdict, "explain": explain_reach} if _thesis_reward else {}
    _task = ReachTask(**{name: value for name, value in _options.items() if name != "stand_in"})
    register(
        EnvEntry(
            _env_id,
            _alias,
            reward=partial(_task.observed_reward, tie_break=TIE_BREAK, stillness=STILLNESS),
            complete_observation=_task.complete_observation,
            **_judged,
        ),
        "drrl.envs.baxter.env:BaxterReachEnv",
        "drrl.envs.baxter.env:BaxterReachVectorEnv",
        _options,
    )

STACKING: dict[str, tuple[str, dict[str, Any], bool]] = {  # alias, Gymnasium id, task options, thesis reward
    "baxter-stack": ("drrl/BaxterStack-v0", {}, True),  # a stack of two, fixed positions: the thesis's setting
    "baxter-stack-random": ("drrl/BaxterStackRandom-v0", {"positions": "random"}, True),
    "baxter-stack3": ("drrl/BaxterStack3-v0", {"blocks": 3}, True),
    "baxter-stack3-random": ("drrl/BaxterStack3Random-v0", {"blocks": 3, "positions": "random"}, True),
    "baxter-stack-dense": ("drrl/BaxterStackDense-v0", {"reward": "dense"}, False),
    # the grip point's velocity through the arm's Jacobian instead of joint velocities (``stacking``)
    "baxter-stack-end-point": ("drrl/BaxterStackEndPoint-v0", {"controller": "end_point"}, True),
    "baxter-stack-random-end-point": (
        "drrl/BaxterStackRandomEndPoint-v0",
        {"positions": "random", "controller": "end_point"},
        True,
    ),
    "baxter-stack3-end-point": ("drrl/BaxterStack3EndPoint-v0", {"blocks": 3, "controller": "end_point"}, True),
    "baxter-stack3-random-end-point": (
        "drrl/BaxterStack3RandomEndPoint-v0",
        {"blocks": 3, "positions": "random", "controller": "end_point"},
        True,
    ),
    "baxter-stack-dense-end-point": (
        "drrl/BaxterStackDenseEndPoint-v0",
        {"reward": "dense", "controller": "end_point"},
        False,
    ),
}

for _alias, (_env_id, _options, _thesis_reward) in STACKING.items():
    _scripted = _options.get("controller") == "end_point"  # the scripted stacker acts through end-point actions
    register(
        EnvEntry(
            _env_id,
            _alias,
            verdict=stack_verdict if _thesis_reward else None,
            explain=explain_stack if _thesis_reward else None,
            demonstrator=ScriptedStacker(StackTask(**_options)).act if _scripted else None,
        ),
        "drrl.envs.baxter.stack_env:BaxterStackEnv",
        "drrl.envs.baxter.stack_env:BaxterStackVectorEnv",
        _options,
    )
