"""Gymnasium's envs spread over worker processes, one block of slots each: the ``gymnasium`` engine on every core.

For envs whose step is expensive (Gymnasium's MuJoCo tasks) and that EnvPool does not ship. Each worker makes the
same envs the ``serial`` engine makes for its block of slots and steps only the running ones, so the episodes are the
serial engine's, step for step, whatever the number of workers. A step costs one message to and from every worker
with running slots (tens of microseconds): for envs that step in microseconds (classic control) one process is
faster.

Workers are started with ``forkserver`` (``spawn`` where it does not exist), never ``fork``: a forked copy of a
process running PyTorch's or MuJoCo's threads can hang.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np

from drrl.envs.cores import available_cores
from drrl.envs.serial import SerialEpisodes
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
    """``num_envs`` copies of ``gymnasium.make(env_id, **options)`` over ``workers`` processes (default: one per
    core this process may use, at most one per env), contiguous blocks of slots each."""

    def __init__(
        self, env_id: str, num_envs: int, options: Mapping[str, Any] | None = None, workers: int | None = None
    ):
        # made here first, so that a missing dependency or a bad option fails as it does on the serial engine
        probe = gymnasium.make(env_id, disable_env_checker=True, **(options or {}))
        probe.close()
        workers = max(1, min(workers or available_cores(), num_envs))
        self._bounds = np.linspace(0, num_envs, workers + 1).round().astype(int)
        methods = multiprocessing.get_all_start_methods()
        context: Any = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
        self._connections, self._processes = [], []
        try:
            for low, high in zip(self._bounds[:-1], self._bounds[1:], strict=True):
                ours, theirs = context.Pipe()
                process = context.Process(
                    target=_serve, args=(theirs, env_id, int(high - low), dict(options or {})), daemon=True
                )
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
        for connection, low, high in self._blocks():
            connection.send(("start", list(seeds[low:high])))
        return np.concatenate(self._gather(self._connections))

    def advance(self, slots, actions):
        asked = []
        for connection, low, high in self._blocks():
            mine = (slots >= low) & (slots < high)
            if mine.any():
                connection.send(("advance", slots[mine] - low, actions[mine]))
                asked.append(connection)
        answers = self._gather(asked)  # blocks in ascending order, as the slots
        return tuple(np.concatenate(parts) for parts in zip(*answers, strict=True))

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

    def _blocks(self):
        return zip(self._connections, self._bounds[:-1], self._bounds[1:], strict=True)

    @staticmethod
    def _gather(connections) -> list:
        """Every worker's answer, in order; raises for the first that failed once all have answered."""
        answers = []
        for connection in connections:
            try:
                answers.append(connection.recv())
            except EOFError:
                answers.append(("error", "its process ended unexpectedly"))
        failed = [message for status, message in answers if status == "error"]
        if failed:
            raise RuntimeError(f"an env worker failed: {failed[0]}")
        return [answer for _, answer in answers]
