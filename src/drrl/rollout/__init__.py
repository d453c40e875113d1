"""Evaluating candidates on batched environments, here (local) or on a Ray cluster."""

from drrl.rollout.backend import Backend, Workload
from drrl.rollout.evaluate import Evaluation, NonFiniteOutput, episode_seeds, evaluate
from drrl.rollout.local import LocalBackend

BACKENDS = ("local", "ray")


def make_backend(name: str, workload: Workload, address: str | None = None, workers: int | None = None) -> Backend:
    """The ``local`` backend (this process) or the ``ray`` one (actors on a Ray cluster at ``address``)."""
    if name == "local":
        if address is not None or workers is not None:
            raise ValueError("--address and --workers are for --backend ray")
        return LocalBackend(workload)
    if name == "ray":
        try:
            from drrl.rollout.ray import RayBackend
        except ImportError as error:
            raise ValueError(str(error)) from None
        return RayBackend(workload, address=address, workers=workers)
    raise ValueError(f"unknown backend {name!r}; choose one of: {', '.join(BACKENDS)}")


__all__ = [
    "BACKENDS",
    "Backend",
    "Evaluation",
    "LocalBackend",
    "NonFiniteOutput",
    "Workload",
    "episode_seeds",
    "evaluate",
    "make_backend",
]
