"""What the training loop tells the outside: subscribers of ``drrl.training.loop.run``, attached, not wired in.

* ``RunFolderWriter``: config.json, a metrics.csv row per step, checkpoints, the learning curve at the end;
* ``ProgressBar``: real episodes spent, with the step's returns (tqdm);
* ``TensorBoardLogger``: every metric against real training episodes (``drrl[tensorboard]``);
* ``ModelGuard``: a warning when the world model promises the centre far more than reality gives it.

A subscriber overrides any of ``drrl.training.loop.Subscriber``'s ``started``, ``row``, ``checkpoint`` and ``ended``;
a benchmark attaches its own probe the same way.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from tqdm import tqdm

from drrl.runs import RunFolder
from drrl.settings import ModelBasedSettings
from drrl.training.loop import Counters, Setup, Subscriber

INSTALL_TENSORBOARD = '--tensorboard needs TensorBoard, which is not installed: pip install "drrl[tensorboard]"'


class RunFolderWriter(Subscriber):
    """Writes the run folder, which it holds for the run (``RunFolder.claim``): the config and a first checkpoint at
    the start (a run killed before its first checkpoint can still be resumed), a metrics row per step, every
    checkpoint, and at the end the last whole step's checkpoint and the learning curve."""

    def __init__(self, folder: RunFolder):
        self.folder = folder

    def started(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        self.folder.claim()
        if counters.iteration == 0:
            self.folder.write_config(setup.config)
            self.folder.save_checkpoint(snapshot)

    def row(self, setup: Setup, counters: Counters, row: dict) -> None:
        self.folder.append_metrics(row)

    def checkpoint(self, snapshot: dict) -> None:
        self.folder.save_checkpoint(snapshot)

    def ended(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        try:
            self.folder.save_checkpoint(snapshot)
            if counters.iteration:
                self.folder.plot_learning_curve(
                    setup.world.title(setup),
                    counters.best_iteration or None,
                    setup.config.measuring.eval_episodes,
                    setup.world.training,
                )
        finally:
            self.folder.release()


class ProgressBar(Subscriber):
    """Real training episodes spent out of the budget, and the last step's returns; while a long step runs, what it
    is doing."""

    def __init__(self, description: str = "real episodes"):
        self.description = description
        self.bar: Any = None  # a tqdm bar, from started()

    def started(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        self.bar = tqdm(
            total=setup.world.real_budget,
            unit="ep",
            initial=counters.real_episodes,
            desc=self.description,
            dynamic_ncols=True,
        )

    def row(self, setup: Setup, counters: Counters, row: dict) -> None:
        self.bar.update(counters.real_episodes - self.bar.n)
        shown = {
            "return mean": row["mean_return"],
            "best": row.get("best_return"),
            "centre": row["center_return"],
            "model": row.get("imagined_center_return"),
        }
        attempt = f" (attempt {row['attempt']})" if "attempt" in row else ""
        self.bar.set_postfix_str(
            f"{setup.world.unit} {counters.iteration}{attempt} | "
            + " ".join(
                f"{name} {value:.1f}" for name, value in shown.items() if value is not None and not math.isnan(value)
            ),
            refresh=False,
        )

    def doing(self, setup: Setup, counters: Counters, doing: str) -> None:
        self.bar.update(counters.real_episodes - self.bar.n)
        self.bar.set_postfix_str(f"{setup.world.unit} {counters.iteration + 1}: {doing}")

    def ended(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        if self.bar is not None:
            self.bar.close()


class TensorBoardLogger(Subscriber):
    """Every numeric metric of a row as a TensorBoard scalar, against real training episodes (the thesis's axis),
    into ``log_dir`` (``tensorboard --logdir RUN``)."""

    def __init__(self, log_dir: Path | str):
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:
            raise ImportError(INSTALL_TENSORBOARD) from None
        self.writer = SummaryWriter(str(log_dir))

    def row(self, setup: Setup, counters: Counters, row: dict) -> None:
        for name, value in row.items():
            if isinstance(value, (int, float)) and not math.isnan(value) and name != "real_episodes":
                self.writer.add_scalar(name, value, global_step=counters.real_episodes)
        self.writer.flush()

    def ended(self, setup: Setup, counters: Counters, snapshot: dict) -> None:
        self.writer.close()


class ModelGuard(Subscriber):
    """Warns when a model-based iteration's centre earns far less in reality than in the model: the search has
    found the model's errors rather than a better policy (the curse of model bias, thesis 2.3). "Far": the
    imagined return exceeds the real one by more than ``tolerance`` of the larger of the two in size. What to try is
    said with the first warning of a run; later ones give the figures alone."""

    def __init__(self, tolerance: float = 0.5, say=tqdm.write):
        self.tolerance, self.say = tolerance, say
        self.warned = 0

    def row(self, setup: Setup, counters: Counters, row: dict) -> None:
        promised, real = row.get("imagined_center_return"), row["center_return"]
        if promised is None or math.isnan(real) or promised - real <= self.tolerance * max(abs(promised), abs(real)):
            return
        self.warned += 1
        advice = (
            "the search is exploiting the model's errors. Try "
            + ", ".join(remedies(None if setup is None else setup.config.model_based))
            if self.warned == 1
            else "exploited again"
        )
        self.say(
            f"warning: iteration {counters.iteration}: the world model promised the centre {promised:.1f}, "
            f"reality gave {real:.1f}; {advice}"
        )


def remedies(settings: ModelBasedSettings | None) -> list[str]:
    """What helps a model that the search exploits, of what the run does not do already."""
    settings = settings or ModelBasedSettings.model_validate({})
    larger = (
        "a recurrent model (--model-kind rnn or lstm)"  # a least-squares model has no width to grow
        if settings.model_kind in ("linear", "polynomial")
        else "a larger model (--model-hidden)"
    )
    return [
        *(["an ensemble (--ensemble 5)"] if settings.ensemble_size == 1 else []),
        *([] if settings.disagreement_penalty else ["a disagreement penalty (disagreement_penalty in [model_based])"]),
        larger,
        "or more real episodes per iteration (episodes_per_iteration in [model_based])",
    ]
