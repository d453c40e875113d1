"""Gymnasium's envs spread over worker processes, every W-th slot each: the ``gymnasium`` engine on every core.

For envs whose step is expensive (Gymnasium's MuJoCo tasks) and that EnvPool does not ship. Worker w of W makes the
same envs the ``serial`` engine makes for slots w, w + W, w + 2W, ... and steps only the running ones, so the
episodes are the serial engine's, step for step, whatever the number of workers. Slots are dealt out in turn, not in
blocks, so that the episodes still running late in a batch are shared among the workers. A step costs one message
to and from every worker with running slots (a fraction of a millisecond): it pays where many envs run at once and
each step is expensive; late in a batch of very uneven episodes, with few envs left running, it does not.

A script that uses this engine needs the ``if __name__ == "__main__":`` guard around its work, as any use of
Python's ``multiprocessing`` outside ``fork`` does: each worker imports the script's main module.

Workers are started with ``forkserver`` (``spawn`` where it does not exist), never ``fork``: a forked copy of a
process running PyTorch's or MuJoCo's threads can hang.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
from collections.abc import Mapping
from typing import Any

import numpy as np

from drrl.envs.cores import available_cores
from drrl.envs.serial import SerialEpisodes, make_env
from drrl.envs.slots import EpisodeSlots


def _serve(connection, env_id: str, num_envs: int, options: dict[str, Any]) -> None:
    """A worker: the serial engine's envs for its slots, answering ("start", seeds), ("advance", slots, actions) and
    ("close",) until closed; an error is sent back as its message. Ctrl-C reaches the whole process group: the
    worker leaves it to the training process, which checkpoints and then closes its workers."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        envs = SerialEpisodes(env_id, num_envs, options)
    except Exception as error:
        connection.send(("error", f"{type(error).__name__}: {error}"))
        return
    connection.send(("ok", None))
    try:
        while True:
            command, *arguments = connection.recv()
            if command == "close":
                break
            try:
                answer = envs.start(*arguments) if command == "start" else envs.advance(*arguments)
                connection.send(("ok", answer))
            except Exception as error:
                connection.send(("error", f"{type(error).__name__}: {error}"))
    finally:
        envs.close()
        connection.close()


class ProcessEpisodes(EpisodeSlots):
    """``num_envs`` copies of ``make_env(env_id, options)`` over ``workers`` processes (default: one per
    core this process may use, at most one per env), worker w holding slots w, w + W, ...."""

    def __init__(
        self, env_id: str, num_envs: int, options: Mapping[str, Any] | None = None, workers: int | None = None
    ):
        # made here first, so that a missing dependency or a bad option fails as it does on the serial engine
        probe = make_env(env_id, options)
        probe.close()
        workers = max(1, min(workers or available_cores(), num_envs))
        methods = multiprocessing.get_all_start_methods()
        context: Any = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
        self._connections, self._processes = [], []
        try:
            for worker in range(workers):
                ours, theirs = context.Pipe()
                slots = len(range(worker, num_envs, workers))
                process = context.Process(target=_serve, args=(theirs, env_id, slots, dict(options or {})), daemon=True)
                process.start()
                theirs.close()
                self._connections.append(ours)
                self._processes.append(process)
            self._gather(self._connections)  # each worker has made its envs
        except BaseException:
            self.close_extras()
            raise
        super().__init__(num_envs, probe.observation_space, probe.action_space)

    @property
    def workers(self) -> int:
        return len(self._processes)

    def start(self, seeds):
        for worker, connection in enumerate(self._connections):
            connection.send(("start", list(seeds[worker :: self.workers])))
        answers = self._gather(self._connections)  # every worker holds at least one slot
        observations = np.empty((self.num_envs, *answers[0].shape[1:]), dtype=answers[0].dtype)
        for worker, answer in enumerate(answers):
            observations[worker :: self.workers] = answer
        return observations

    def advance(self, slots, actions):
        owners = slots % self.workers
        asked = []
        for worker, connection in enumerate(self._connections):
            mine = owners == worker
            if mine.any():
                connection.send(("advance", slots[mine] // self.workers, actions[mine]))
                asked.append(connection)
        answers = self._gather(asked)  # in the order of the workers
        order = np.argsort(owners, kind="stable")  # the slots as the workers' answers list them
        results = []
        for parts in zip(*answers, strict=True):
            stacked = np.concatenate(parts)
            result = np.empty_like(stacked)
            result[order] = stacked
            results.append(result)
        return tuple(results)

    def close_extras(self, **kwargs):
        for connection in self._connections:
            with contextlib.suppress(BrokenPipeError, OSError):
                connection.send(("close",))
        for process in self._processes:
            process.join(timeout=5)
            if process.is_alive():
                process.terminate()
        for connection in self._connections:
            connection.close()
        self._connections, self._processes = [], []

    @staticmethod
    def _gather(connections) -> list:
        """Every worker's answer, in order; raises for the first that failed once all have answered."""
        answers = []
        for connection in connections:
            try:
                answers.append(connection.recv())
            except EOFError:
                answers.append(
                    ("error", 'its process ended (a script using this engine needs if __name__ == "__main__":)')
                )
        failed = [message for status, message in answers if status == "error"]
        if failed:
            raise RuntimeError(f"an env worker failed: {failed[0]}")
        return [answer for _, answer in answers]
