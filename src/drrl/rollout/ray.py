"""The Ray backend: a generation's candidates split into chunks, each evaluated by a Ray actor holding a batched env.

Chunk k always holds the same candidates (consecutive slices of the population, one per worker) and is evaluated
with the generation's seed, so the returns are those of the local backend bit for bit, whichever actor ran it.
A chunk whose actor died is detected by ``ray.get`` raising ``ray.exceptions.RayActorError``
(``ActorDiedError``); the chunk is run again on the next actor, up to ``MAX_ATTEMPTS`` times, and the dead actor
is replaced by a new one. Parameters and results cross between processes through Ray's object store; nothing
is read back from disk.
"""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
import warnings
from typing import Any, cast

import numpy as np
import torch
from gymnasium.vector import VectorEnv

from drrl.rollout.backend import Workload, chunk_bounds
from drrl.rollout.evaluate import Evaluation, evaluate
from drrl.rollout.memory import retain_freed_memory

INSTALL_HINT = '--backend ray needs Ray, which is not installed: pip install "drrl[ray]"'
MAX_ATTEMPTS = 4  # runs of one chunk in one generation before the run gives up
START_TIMEOUT = 120  # seconds for the actors to start
CONNECT_TIMEOUT = 10  # seconds for a cluster address to answer and be joined
LISTENS_EVERYWHERE = (
    "the local Ray drrl starts listens on every network interface, not on 127.0.0.1 alone: its GCS, raylet, "
    "runtime-env agent, workers and this process (Ray has no setting that binds them to one address); on a shared "
    "machine, keep its ports behind a firewall or use --backend local"
)

try:
    import ray
    from ray.exceptions import GetTimeoutError, RayActorError, RayTaskError
except ImportError as error:
    raise ImportError(INSTALL_HINT) from error


class RolloutWorker:
    """One Ray actor: evaluates chunks of candidates on batched envs it keeps, one per chunk size."""

    def __init__(self, workload: Workload, candidates: int):
        retain_freed_memory()
        self.workload = workload
        self.envs: dict[int, VectorEnv] = {}
        self._env(candidates)  # made now, so a bad env fails at start-up and the first generation is not slower

    def _env(self, candidates: int):
        if candidates not in self.envs:
            self.envs[candidates] = self.workload.env.make(candidates * self.workload.episodes)
        return self.envs[candidates]

    def use(self, workload: Workload, candidates: int) -> None:
        for env in self.envs.values():
            env.close()
        self.workload, self.envs = workload, {}
        self._env(candidates)

    def evaluate(self, params: np.ndarray, seed: int) -> Evaluation:
        work = self.workload
        env = self._env(params.shape[0])
        return evaluate(
            work.policy,
            torch.tensor(params),
            env,
            work.episodes,
            seed=seed,
            moments=work.moments,
            max_steps=work.max_steps,
        )

    def pid(self) -> int:
        return os.getpid()


# The actor class, one CPU each; typed Any, as Ray's stubs do not give its methods their .remote
RemoteWorker: Any = ray.remote(num_cpus=1)(RolloutWorker)


class RayBackend:
    """Candidates in chunks over ``workers`` Ray actors (default: one per CPU of the cluster).

    Connects to the cluster at ``address``, or starts a local Ray when there is none; a Ray already initialised in
    this process is used as it is (and left running on close).
    """

    def __init__(self, workload: Workload, address: str | None = None, workers: int | None = None):
        self.workload = workload
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            _check_reachable(address)
            if address is None:
                warnings.warn(LISTENS_EVERYWHERE, stacklevel=2)
            try:
                ray.init(address=address, include_dashboard=False, logging_level=logging.WARNING)
            except ConnectionError as error:
                raise ValueError(f"cannot join the Ray cluster at {address}: {error}") from None
        cpus = int(ray.cluster_resources().get("CPU", 0))
        if (workers or 1) > cpus:
            self.close()
            raise ValueError(f"{workers or 1} Ray worker(s) need as many CPUs, but the Ray cluster has {cpus}")
        self.chunks = chunk_bounds(workload.popsize, min(workers or cpus, workload.popsize))
        self.workers = [RemoteWorker.remote(workload, stop - start) for start, stop in self.chunks]
        self.lost = 0  # chunks run again because their worker died
        try:
            ray.get([worker.pid.remote() for worker in self.workers], timeout=START_TIMEOUT)
        except GetTimeoutError:
            self.close()
            raise ValueError(f"the Ray workers did not start within {START_TIMEOUT} s; is the cluster busy?") from None

    def evaluate(self, params: torch.Tensor, seed: int) -> Evaluation:
        parts = [params[start:stop].detach().cpu().numpy() for start, stop in self.chunks]
        pending = dict(self._submit(index, 0, parts, seed) for index in range(len(parts)))
        results: list[Evaluation | None] = [None] * len(parts)
        while pending:
            [ready], _ = ray.wait(list(pending), num_returns=1)
            index, attempt, worker = pending.pop(ready)
            try:
                results[index] = ray.get(ready)
            except RayTaskError as error:  # the env or the policy raised: the same error as the local backend's
                raise error.cause from None
            except RayActorError as error:
                if attempt + 1 >= MAX_ATTEMPTS:
                    raise RuntimeError(
                        f"chunk {index} lost its Ray worker {MAX_ATTEMPTS} times; giving up: {error}"
                    ) from None
                self.lost += 1
                start, stop = self.chunks[index]
                warnings.warn(
                    f"a Ray worker died while evaluating candidates {start}–{stop - 1}; running them "
                    f"again on another worker",
                    stacklevel=2,
                )
                self._replace(worker)
                pending.update([self._submit(index, attempt + 1, parts, seed)])
        return Evaluation.concat(cast(list[Evaluation], results))  # every chunk came back

    def _submit(self, index: int, attempt: int, parts: list[np.ndarray], seed: int):
        """Chunk ``index`` on its own worker first, then on the next ones round the pool: (ref, what it runs)."""
        worker = self.workers[(index + attempt) % len(self.workers)]
        return worker.evaluate.remote(parts[index], seed), (index, attempt, worker)

    def _replace(self, dead) -> None:
        """A new actor in the place of ``dead`` (unless another chunk's failure replaced it already)."""
        for slot, worker in enumerate(self.workers):
            if worker is dead:
                ray.kill(dead)
                start, stop = self.chunks[slot]
                self.workers[slot] = RemoteWorker.remote(self.workload, stop - start)

    def use(self, workload: Workload) -> None:
        if (workload.popsize, workload.episodes) != (self.workload.popsize, self.workload.episodes):
            raise ValueError("a Ray backend keeps its popsize and episodes; make a new one for others")
        self.workload = workload
        shared = ray.put(workload)  # sent once, read by every worker
        ray.get(
            [
                worker.use.remote(shared, stop - start)
                for worker, (start, stop) in zip(self.workers, self.chunks, strict=True)
            ]
        )

    def pids(self) -> list[int]:
        """The process ids of the workers (for tests that kill one)."""
        return ray.get([worker.pid.remote() for worker in self.workers])

    def close(self) -> None:
        for worker in getattr(self, "workers", []):
            ray.kill(worker)
        self.workers = []
        if self._owns_ray:
            ray.shutdown()


def _check_reachable(address: str | None) -> None:
    """Refuse, within about ``CONNECT_TIMEOUT`` seconds, a cluster address Ray could not join: not HOST:PORT, a port
    out of range, nothing answering, or something that answers but is not a Ray cluster (Ray itself would retry for
    minutes). The join is tried in a child process, which is stopped when the time is up."""
    if address is None or address == "auto":
        return
    host, port = _host_and_port(address)
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT).close()
    except OSError as error:
        raise ValueError(
            f"nothing answers at the Ray cluster address {address} ({error.strerror or error}); is "
            f"the cluster up (ray start --head)?"
        ) from None
    join = f"import ray; ray.init(address={address!r}, include_dashboard=False, logging_level='ERROR')"
    try:
        subprocess.run([sys.executable, "-c", join], capture_output=True, timeout=CONNECT_TIMEOUT, check=True)
    except subprocess.TimeoutExpired as error:
        said = f" (Ray: {_last_line(error.stderr)})" if error.stderr else ""
        raise ValueError(
            f"something answers at {address}, but no Ray cluster could be joined there within {CONNECT_TIMEOUT} "
            f"s{said}; is it the head node's GCS port (6379 unless ray start --port said otherwise)?"
        ) from None
    except subprocess.CalledProcessError as error:
        raise ValueError(f"cannot join the Ray cluster at {address}: {_last_line(error.stderr)}") from None


def _last_line(output: bytes | None) -> str:
    """The last line a Ray process wrote, without its log prefix, for a one-line message."""
    lines = (output or b"").decode(errors="replace").strip().splitlines() or ["no message"]
    return lines[-1].rpartition("] ")[2][:200]


def _host_and_port(address: str) -> tuple[str, int]:
    """HOST and PORT of ``address`` (HOST:PORT, [IPv6]:PORT, optionally after ray://), the port from 1 to 65535."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    host = host.removeprefix("[").removesuffix("]") if host.startswith("[") else host
    if not host or not (port.isascii() and port.isdigit()):
        raise ValueError(f"--address {address!r} is not HOST:PORT (e.g. 10.0.0.1:6379, or [::1]:6379 for IPv6)")
    if not 1 <= int(port) <= 65535:
        raise ValueError(f"--address {address!r}: port {int(port)} is out of range; a port is from 1 to 65535")
    return host, int(port)
