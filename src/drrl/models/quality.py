"""How good is a world model? k-step prediction error against k on held-out real episodes, and what overshooting
(3.3.2) and dynamical consistency (3.3.3) each contribute to it.

The error is measured as imagination uses the model: from one real observation, the model predicts k steps ahead
feeding back its own predictions (or zeros, for a model trained that way), with the actions the real episode took.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from drrl.models.base import LearnedModel
from drrl.models.data import EpisodeBuffer
from drrl.models.fit import FitSettings, fit
from drrl.models.recurrent import WorldModel


def k_step_errors(model: LearnedModel, episodes: EpisodeBuffer, max_k: int) -> np.ndarray:
    """(max_k,) error of the k-step predicted observation, k = 1..max_k: for every start in ``episodes`` the
    root-mean-square over the observation's entries, in units of each entry's per-step change (the model's
    ``change_scale``); then the median over the members and the starts whose k-th step lies inside their episode.
    The median, because a few starts just before a fall, far from most data, would otherwise decide the mean."""
    windows = episodes.windows(1, max_k - 1).to(model.device)
    with torch.no_grad():
        prediction = model.unfold(windows.observations, windows.actions, 1, windows.previous_actions)
        error = (
            ((prediction.observations - windows.next_observations) / model.change_scale[:, None, None])
            .square()
            .mean(-1)
            .sqrt()
        )  # (K, W, L)
    inside = windows.mask.bool()
    return np.array([float(error[:, inside[:, k], k].median()) for k in range(max_k)])


def variants(overshoot: int) -> dict[str, dict]:
    """The models compared: finite unfolding alone, overshooting as 3.5 (zero inputs), and with consistency."""
    return {
        "finite unfolding only (m = 0)": dict(overshoot=0, future_inputs="predictions"),
        f"overshooting m = {overshoot}, zero inputs (3.5)": dict(overshoot=overshoot, future_inputs="zeros"),
        f"overshooting m = {overshoot} + dynamical consistency": dict(overshoot=overshoot, future_inputs="predictions"),
    }


def model_quality_report(
    training: EpisodeBuffer,
    held_out: EpisodeBuffer,
    path: Path | str | None = None,
    max_k: int = 30,
    settings: FitSettings = FitSettings(),
    hidden=(64,),
    kind: str = "rnn",
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """Fit each of ``variants`` on ``training`` and return (and plot to ``path``, a PNG) its k-step errors on
    ``held_out``, k = 1..max_k."""
    observation_size = training.episodes[0].observations.shape[1]
    action_size = training.episodes[0].actions.shape[1]
    curves = {}
    for label, variant in variants(settings.overshoot).items():
        torch.manual_seed(seed)
        model = WorldModel(observation_size, action_size, hidden, kind, variant["future_inputs"])
        fit(model, training, dataclasses.replace(settings, overshoot=variant["overshoot"]), seed=seed)
        curves[label] = k_step_errors(model, held_out, max_k)
    if path is not None:
        plot_k_step_errors(
            curves,
            Path(path),
            f"{kind} world model {'×'.join(map(str, hidden))}, "
            f"{len(training)} training / {len(held_out)} held-out episodes",
        )
    return curves


def plot_k_step_errors(curves: dict[str, np.ndarray], path: Path, title: str) -> Path:
    """``k_step_figure`` written to ``path``."""
    import matplotlib.pyplot as plt

    figure = k_step_figure(curves, title)
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path


def k_step_figure(curves: dict[str, np.ndarray], title: str):
    """Each variant's median k-step error against k (whole steps). A matplotlib figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    figure, axes = plt.subplots(figsize=(6.4, 4.0), layout="constrained")
    for label, errors in curves.items():
        axes.plot(np.arange(1, len(errors) + 1), errors, marker=".", label=label)
    axes.set_yscale("log")
    axes.xaxis.set_major_locator(MaxNLocator(integer=True))
    axes.set_xlabel("prediction horizon k (steps)")
    axes.set_ylabel("median error (units of per-step change)")
    axes.set_title(title, fontsize=9)
    axes.legend(fontsize=8)
    axes.grid(alpha=0.3, which="both")
    return figure
