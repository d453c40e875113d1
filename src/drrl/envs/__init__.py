"""drrl's environments, registered with Gymnasium on import.

``gymnasium.make(id)`` gives the single :class:`~drrl.envs.cartpole.CartPoleEnv` and
``gymnasium.make_vec(id, num_envs=N)`` the native batched :class:`~drrl.envs.cartpole.CartPoleVectorEnv`, for

* ``drrl/CartPole-v0``: the thesis's balance task (5.1), fully observed;
* ``drrl/CartPolePO-v0``: the same task observing only (s, θ), a POMDP (2.1.1);
* ``drrl/CartPoleSwingUp-v0``: swing the pole up from hanging down and hold it upright.

The environments end episodes at the task's horizon themselves, so no TimeLimit wrapper is registered.
"""

import gymnasium

from drrl.envs import baxter as _baxter  # noqa: F401  (registers drrl/BaxterReach*-v0; MuJoCo loads on make)
from drrl.envs.cartpole import PartiallyObservedTask, SwingUpTask

gymnasium.register(
    id="drrl/CartPole-v0",
    entry_point="drrl.envs.cartpole:CartPoleEnv",
    vector_entry_point="drrl.envs.cartpole:CartPoleVectorEnv",
)

VARIANTS = {"drrl/CartPolePO-v0": PartiallyObservedTask(), "drrl/CartPoleSwingUp-v0": SwingUpTask()}

for _env_id, _task in VARIANTS.items():
    gymnasium.register(
        id=_env_id,
        entry_point="drrl.envs.cartpole:CartPoleEnv",
        vector_entry_point="drrl.envs.cartpole:CartPoleVectorEnv",
        kwargs={"task": _task},
    )
