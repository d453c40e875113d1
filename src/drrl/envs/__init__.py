"""drrl's environments, registered with Gymnasium on import.

``gymnasium.make("drrl/CartPole-v0")`` gives the single :class:`~drrl.envs.cartpole.CartPoleEnv` and
``gymnasium.make_vec("drrl/CartPole-v0", num_envs=N)`` the native batched
:class:`~drrl.envs.cartpole.CartPoleVectorEnv`. The environments end episodes at the task's horizon (200 steps)
themselves, so no TimeLimit wrapper is registered.
"""

import gymnasium

gymnasium.register(
    id="drrl/CartPole-v0",
    entry_point="drrl.envs.cartpole:CartPoleEnv",
    vector_entry_point="drrl.envs.cartpole:CartPoleVectorEnv",
)
