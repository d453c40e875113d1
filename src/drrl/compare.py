"""``drrl compare``: the thesis's Figure 5.2 reproduced, extended with model-based PGPE and set against the
action-space policy gradients the thesis argues against.

The methods: PGPE with its three samplers (REINFORCE-PGPE 2.28–2.29, SyS-PGPE 2.31–2.33, super-symmetric PGPE),
model-based PGPE (2.3), REINFORCE with a baseline and eNAC in action space (2.2.2, 2.1.4;
``drrl.training.action_space``), and, as an outside reference, Stable-Baselines3's PPO (``drrl.reference_ppo``, extra
``drrl[sb3]``). For each method and each of N seeds, a run on the same task records the centre policy's average
return over ``eval_episodes`` fresh real episodes against the real training episodes spent so far. Each run's curve
is held constant between its measurements (the centre policy does not change there), read on a common grid of real
episodes, and summarised by the mean over seeds and a confidence band of one standard error of that mean on either
side (about 68 %; none for a single seed). One standard error rather than 95 %: with the few seeds of a quick
comparison a 95 % band needs Student's t quantiles (4.3 for 3 seeds), and a plain ±1 s.e. band reads the same at
any N.

Departure from Figure 5.2: the thesis plots one run per method and a linear axis; here the axis of real episodes
is logarithmic, because model-based PGPE spends tens of real episodes where the model-free methods spend
hundreds.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drrl.settings import TrainConfig
from drrl.settings.flat import FLAT, run_kind, settings_of
from drrl.settings.presets import task_settings
from drrl.training.train import train

MODEL_FREE = {"REINFORCE-PGPE": "single", "SyS-PGPE": "symmetric", "super-symmetric PGPE": "supersymmetric"}
MODEL_BASED = "model-based PGPE"
ACTION_SPACE = {"REINFORCE": "reinforce", "eNAC": "enac"}
PPO = "PPO (SB3)"
METHODS = (*MODEL_FREE, MODEL_BASED, *ACTION_SPACE, PPO)
DEFAULT_METHODS = METHODS[:-1]  # PPO needs an extra
# The settings of the task rather than of a method: every method takes them from the shared settings.
TASK_SETTINGS = ("env", "policy", "max_steps", "eval_episodes", "eval_every", "eval_share", "engine", "device")
_ANY_RUN = {"search", "model_based", *FLAT}  # the flat settings of some run


@dataclass(frozen=True)
class Curve:
    """One method's mean return over seeds, and its ±1 standard-error band, at ``real_episodes``."""

    method: str
    real_episodes: np.ndarray
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray
    seeds: int


def method_config(method: str, seed: int, budget: int, settings: dict) -> TrainConfig:
    """The run config of ``method``: the shared ``settings`` (TrainConfig fields), then the method's own.

    The PGPE methods are PGPE with their sampler whatever search ``settings`` or the env's own settings name (Pendulum's
    is CMA-ES), keep ``settings``' policy and search settings and measure their centre after every generation
    (``eval_share`` 1, unless ``settings`` say otherwise), for curves as fine as the model-based ones; REINFORCE needs
    no pairs and super-symmetric PGPE needs a popsize divisible by 4, so their popsize is rounded up to 8 where
    smaller. The action-space methods take the task's settings (``TASK_SETTINGS``) and their own presets: PGPE's
    settings mean nothing to them. On an env with presets of its own (the swing-up's) every method starts from them,
    as ``drrl train`` does. Settings that a method's run does not have (``eval_share`` for a model-based one) are
    left out of its run.
    """
    base = {key: value for key, value in settings.items() if key != "model_based"}
    if method == MODEL_BASED:
        flat = {**base, "budget": budget, "seed": seed, "model_based": settings.get("model_based") or {}}
        return TrainConfig.model_validate(_its_own(flat))
    if method in ACTION_SPACE:
        own = task_settings(base.get("env", "cartpole"), "model-free")
        task = {key: value for key, value in {**own, **base}.items() if key in TASK_SETTINGS}
        return TrainConfig.model_validate(
            {"eval_share": 1.0, **task, "search": ACTION_SPACE[method], "budget": budget, "seed": seed}
        )
    merged = {
        "eval_share": 1.0,
        "restart_every": None,  # a curve follows one search; restarts would start it again
        **base,
        "search": "pgpe",
        "sampler": MODEL_FREE[method],
        "budget": budget,
        "seed": seed,
    }
    if merged["sampler"] == "supersymmetric" and merged.get("popsize", 8) % 4:
        merged["popsize"] = 8
    return TrainConfig.model_validate(_its_own(merged))


def _its_own(flat: dict) -> dict:
    """``flat`` less the settings a run of its kind does not have."""
    own = settings_of(run_kind(flat), str(flat.get("search", "pgpe")))
    return {key: value for key, value in flat.items() if key in own or key not in _ANY_RUN}


def model_based_budget_of(env: str) -> int:
    """The real episodes a model-based run on ``env`` spends unless told."""
    return TrainConfig.model_validate({"env": env, "model_based": {}}).budget


def curve_budget(env: str, default: int) -> int:
    """The real episodes a model-free curve on ``env`` spends unless told: the env's own budget, one attempt's where
    its runs restart (Pendulum-v1's), else ``default``."""
    own = task_settings(env, "model-free")
    if own.get("restart_every"):
        config = TrainConfig.model_validate({"env": env})
        return int(own["restart_every"]) * config.episodes_per_generation
    return int(own.get("budget", default))


def run_method(method: str, seed: int, budget: int, settings: dict) -> list[tuple[int, float]]:
    """(real training episodes, centre's measured return) after each measurement of one run."""
    rows = [row for row in method_rows(method, seed, budget, settings) if row["center_return"] == row["center_return"]]
    return [(int(row["real_episodes"]), float(row["center_return"])) for row in rows]


def method_rows(method: str, seed: int, budget: int, settings: dict) -> list[dict]:
    """One run's metrics rows (PPO's: a row per measurement, in the same columns)."""
    if method == PPO:
        from drrl.reference_ppo import run_ppo

        return run_ppo(settings.get("env", "cartpole"), seed, budget, settings.get("eval_episodes", 50))
    return train(method_config(method, seed, budget, settings)).rows


def summarise(method: str, runs: list[list[tuple[int, float]]], grid: np.ndarray) -> Curve:
    """Mean and ±1 standard-error band over seeds on ``grid`` (real episodes), where every run has a measurement."""
    grid = grid[grid >= max(run[0][0] for run in runs)]
    values = np.stack([_held(run, grid) for run in runs])
    mean = values.mean(0)
    half = values.std(0, ddof=1) / np.sqrt(len(runs)) if len(runs) > 1 else np.zeros_like(mean)
    return Curve(method, grid, mean, mean - half, mean + half, len(runs))


def _held(run: list[tuple[int, float]], grid: np.ndarray) -> np.ndarray:
    """The run's last measured return at or before each grid point."""
    episodes = np.array([e for e, _ in run])
    returns = np.array([r for _, r in run])
    return returns[np.searchsorted(episodes, grid, side="right") - 1]


def compare(
    out: Path,
    seeds: int = 3,
    budget: int = 300,
    model_based_budget: int = 20,
    settings: dict | None = None,
    methods: tuple[str, ...] = DEFAULT_METHODS,
    progress=None,
) -> list[Curve]:
    """Run every method for ``seeds`` seeds; write ``out``/compare.csv and ``out``/compare.png."""
    settings = settings or {}
    if PPO in methods:
        from drrl.reference_ppo import require_sb3

        require_sb3()
    curves = []
    for method in methods:
        method_budget = model_based_budget if method == MODEL_BASED else budget
        runs = []
        for seed in range(seeds):
            runs.append(run_method(method, seed, method_budget, settings))
            if progress is not None:
                progress(method, seed, runs[-1])
        grid = np.unique(np.concatenate([[e for e, _ in run] for run in runs]))
        curves.append(summarise(method, runs, grid))
    out.mkdir(parents=True, exist_ok=True)
    write_csv(curves, out / "compare.csv")
    plot(curves, out / "compare.png", settings.get("env", "cartpole"), settings.get("eval_episodes", 50))
    return curves


def write_csv(curves: list[Curve], path: Path) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["method", "real_episodes", "mean_return", "se_low", "se_high", "seeds"])
        for curve in curves:
            for row in zip(curve.real_episodes, curve.mean, curve.low, curve.high, strict=True):
                writer.writerow([curve.method, int(row[0]), *(round(float(v), 3) for v in row[1:]), curve.seeds])


def plot(curves: list[Curve], path: Path, env: str, eval_episodes: int) -> None:
    """compare.png: ``comparison_figure``."""
    import matplotlib.pyplot as plt

    figure = comparison_figure(curves, env, eval_episodes)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def comparison_figure(curves: list[Curve], env: str, eval_episodes: int):
    """Each method's mean centre return and its ±1 s.e. band against real episodes (a method of one measurement as a
    marker; log axis, ticks at 1, 2, 5, 10, 20, ... episodes, thousands written 1k, 2k, ... so that they do not run
    into each other). A matplotlib figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    figure, axes = plt.subplots(figsize=(7.0, 4.8), layout="constrained")
    for curve in curves:
        (line,) = axes.step(
            curve.real_episodes,
            curve.mean,
            where="post",
            marker="o" if len(curve.real_episodes) == 1 else None,  # a step of one point draws nothing
            label=f"{curve.method} ({curve.seeds} seed{'s' * (curve.seeds > 1)})",
        )
        axes.fill_between(curve.real_episodes, curve.low, curve.high, step="post", alpha=0.2, color=line.get_color())
    axes.set_xscale("log")
    axes.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axes.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:g}k" if x >= 1000 else f"{x:g}"))
    axes.xaxis.set_minor_formatter(NullFormatter())
    axes.set_xlabel("real training episodes")
    axes.set_ylabel(f"centre policy's average return ({eval_episodes} episodes)")
    axes.set_title(f"{env}: mean ± 1 s.e. over seeds (thesis Figure 5.2, extended)", fontsize=9)
    figure.legend(loc="outside lower center", ncols=3, fontsize=8)  # below the axes: no curve hidden behind it
    axes.grid(alpha=0.3, which="both")
    return figure
