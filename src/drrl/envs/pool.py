"""EnvPool's C++ batches (``pip install "drrl[envpool]"``): Gymnasium's classic-control and MuJoCo tasks, stepped
many times faster than one Python env after another.

EnvPool seeds an environment only when it makes it, so a seeded reset makes the pool anew with one seed per
sub-environment: episode e of every candidate then starts from the same state, as on the other engines. EnvPool
takes 31-bit seeds; drrl's 64-bit episode seeds are cut to their low 31 bits. Its episodes are EnvPool's own
implementation of each task, not bit for bit Gymnasium's, so a run's engine is part of its config.

EnvPool steps its envs on worker threads, one per CPU this process may run on: a worker that has to share the
caller's only core makes every step about three times slower (Acrobot, 100 envs: 0.64 ms against 0.19 ms).
Making a pool costs about 2.5 ms per MuJoCo env (its model is parsed anew), paid once a generation.
"""

from __future__ import annotations

import contextlib
import warnings

import numpy as np

from drrl.envs.cores import available_cores
from drrl.envs.slots import EpisodeSlots

SEED_BITS = 31


def installed() -> bool:
    try:
        import envpool  # noqa: F401
    except ImportError:
        return False
    return True


def ships(env_id: str) -> bool:
    """Whether EnvPool (installed) has a task of this Gymnasium id that observes a vector of floats, as Gymnasium's
    does: its toy-text tasks observe a cell's index or raw integers where Gymnasium's observe Discrete values or
    tuples of them, which drrl sees one-hot (``drrl.envs.serial``), so those stay on the gymnasium engine."""
    import envpool

    if env_id not in envpool.list_all_envs():
        return False
    with _quiet():
        space = envpool.make_spec(env_id).observation_space
    return len(space.shape or ()) == 1 and np.issubdtype(space.dtype, np.floating)


class PooledEpisodes(EpisodeSlots):
    """``num_envs`` sub-environments of EnvPool's ``env_id``; its threads step the running ones."""

    def __init__(self, env_id: str, num_envs: int):
        import envpool

        self.env_id = env_id
        with _quiet():
            spec = envpool.make_spec(env_id, num_envs=num_envs)
            observation_space, action_space = spec.gymnasium_observation_space, spec.gymnasium_action_space
        super().__init__(num_envs, observation_space, action_space)
        self._pool = None

    def start(self, seeds):
        import envpool

        if self._pool is None or any(seed is not None for seed in seeds):
            if self._pool is not None:
                self._pool.close()
            fresh = np.random.SeedSequence().generate_state(self.num_envs)  # for the unseeded ones
            env_seeds = [int(fresh[i] if seed is None else seed) % 2**SEED_BITS for i, seed in enumerate(seeds)]
            threads = min(self.num_envs, available_cores())
            self._pool = envpool.make_gymnasium(
                self.env_id, num_envs=self.num_envs, env_seed=env_seeds, num_threads=threads
            )
        with _quiet():  # the first reset builds the pool's spaces
            return self._pool.reset()[0]

    def advance(self, slots, actions):
        observations, rewards, terminated, truncated, info = self._pool.step(actions, slots)
        rows = np.argsort(info["env_id"])  # EnvPool may answer in another order; slots come in ascending order
        return observations[rows], rewards[rows], terminated[rows], truncated[rows]

    def close_extras(self, **kwargs):
        if self._pool is not None:
            self._pool.close()


@contextlib.contextmanager
def _quiet():
    """Silence Gymnasium's warning that EnvPool's float64 space bounds were cast to float32: nothing to act on."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        yield
