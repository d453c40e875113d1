"""drrl's environments, registered with Gymnasium and with drrl's registry (``drrl.envs.registry``) on import.

``gymnasium.make(id)`` gives the single environment and ``gymnasium.make_vec(id, num_envs=N)`` the native batch:

* ``drrl/CartPole-v0`` (``cartpole``): the thesis's balance task (5.1), fully observed;
* ``drrl/CartPolePO-v0`` (``cartpole-po``): the same task observing only (s, θ), a POMDP (2.1.1);
* ``drrl/CartPoleSwingUp-v0`` (``cartpole-swingup``): swing the pole up from hanging down and hold it upright;
* ``drrl/CartPolePixels-v0``, ``drrl/CartPoleSwingUpPixels-v0`` (``cartpole-pixels``, ``cartpole-swingup-pixels``):
  the balance task and the swing-up observed as 64 × 64 grey frames, ``drrl.envs.pixels``;
* ``Pixels/ID`` for any Gymnasium id that renders (``Pixels/Pendulum-v1``, …): ``ID`` observed as the same frames,
  ``drrl.envs.rendered``;
* ``drrl/BaxterReach*-v0`` (``baxter-reach*``): Baxter's arms in MuJoCo (5.2), ``drrl.envs.baxter``.

The environments end episodes at the task's horizon themselves, so no TimeLimit wrapper is registered.
"""

from drrl.envs import baxter as _baxter  # noqa: F401  (MuJoCo loads when a Baxter env is made)
from drrl.envs import cartpole as _cartpole  # noqa: F401
from drrl.envs import pixels as _pixels  # noqa: F401
from drrl.envs import rendered as _rendered  # noqa: F401
