"""Every task's settings, in one place: named presets in the flat form (``drrl.settings.flat``), and which a run
starts from.

A run starts from the schema's defaults (the thesis cart-pole's), then, in this order, the presets that apply to it
(``presets_for``): for a model-based run ``model-based`` and its env's own model-based preset; for an action-space
policy gradient its own (``reinforce``, ``enac``); for a model-free run on an env that is not drrl's own
``gymnasium``; then the env's own model-free preset. ``drrl train TASK --show-settings`` prints the merged settings
and where each came from. The figures behind each preset are in BENCHMARKS.md.
"""

from __future__ import annotations

from typing import Any

import gymnasium

from drrl.envs.registry import is_own, lookup

# ------------------------------------------------------------------------------------------- kinds of runs

# Model-free defaults for Gymnasium's envs (not drrl's own): observations are normalised and actions scaled from
# [-1, 1] to the env's bounds, so one σ suits envs of any scale. A linear policy with a bias (the normalisation's
# shift folds into it), small steps and centred ranks, as ARS (Mania et al. 2018) searched MuJoCo's tasks; chosen on
# Acrobot, MountainCarContinuous, InvertedDoublePendulum, Reacher and Hopper.
GYMNASIUM = {
    "policy": "linear",
    "popsize": 16,
    "sigma_init": 0.025,
    "center_lr": 0.02,
    "fitness_shaping": "centered_ranks",
    "budget": 3200,
}
# A model-based run: 20 real episodes; PGPE in the model with 20 candidates × 10 imagined episodes (many imagined
# episodes per candidate are free, and average out the start states).
MODEL_BASED = {"popsize": 20, "episodes_per_candidate": 10, "budget": 20}
# Action-space policy gradients, chosen on the thesis cart-pole among 12 settings each (step rule and size, initial
# action σ, episodes an update; 3 seeds, 2000–3000 episodes): the ones that reached a near-optimal centre in the
# most seeds. eNAC's regression needs more episodes an update than REINFORCE's gradient.
REINFORCE = {"optimizer": "adam", "center_lr": 0.1, "sigma_init": 1.0, "popsize": 16}
ENAC = {"optimizer": "clipup", "center_lr": 0.05, "sigma_init": 0.5, "popsize": 32}
UNLIMITED_EPISODE_CUT = {"max_steps": 1000}  # an env without a time limit of its own (CliffWalking) would never end

# ------------------------------------------------------------------------------------------- drrl's cart-poles

# The swing-up: a tanh MLP, since a linear policy cannot both pump energy and balance; for its 113 weights a smaller
# σ and a longer step than the cart-pole's, with ranks. Model-free: 200 candidates × 1 episode a generation, solved
# after about 110 generations.
SWING_UP = {
    "policy": "mlp:16",
    "popsize": 200,
    "episodes_per_candidate": 1,
    "fitness_shaping": "centered_ranks",
    "sigma_init": 0.25,
    "sigma_lr": 0.05,
    "center_lr": 0.4,
    "budget": 40_000,
    "eval_every": 10,
}
# Model-based: the same search in the model, 100 generations an iteration without an early stop (it climbs a long
# plateau, a pole that swings up and turns over, too slowly for an early stop to tell progress); an ensemble of five
# sparse polynomial models (a cart-pole's accelerations are near-polynomials of sin θ, cos θ, the velocities and the
# force: they predict many steps ahead from a few episodes, fitted in under a second), also fitted to each real
# episode's mirror image; the new centre kept only if the model rates it above the old one; after the first two
# real episodes, one an iteration, the centre's own, so that every real episode is followed by a new model and a new
# centre; 30 real episodes at most (the LSTM ensemble before it: solved after a median of 18 real episodes).
SWING_UP_MODEL_BASED: dict[str, Any] = {
    **{name: value for name, value in SWING_UP.items() if name not in ("budget", "eval_every")},
    "budget": 30,
    "stop_when_solved": True,  # real episodes are the currency: none spent past a solved centre
    "model_based": {
        "model_kind": "polynomial",
        "ensemble_size": 5,
        "generations_per_iteration": 100,
        "patience": 100,
        "episodes_per_iteration": 1,
        "mirror_episodes": True,
        "keep_unless_improved": True,
    },
}
# The partially observed cart-pole (benchmarks/partially_observed.py): a memory is needed, and a small σ with ranks
# keeps it stable: balanced after a median of 656 real episodes in 10 of 10 seeds, where the default linear policy is
# in 1 of 10.
PARTIALLY_OBSERVED = {
    "policy": "rnn:4",
    "popsize": 16,
    "sigma_init": 0.2,
    "sigma_lr": 0.05,
    "fitness_shaping": "centered_ranks",
    "budget": 2000,
}
# From frames: the state task's model-based search on the latent state (the cart-pole's linear policy on the codes
# and their changes; the swing-up's MLP with an LSTM ensemble), the reward and end learned from it (no closed form
# reads them off frames), and 20 real episodes before the first fit, which the autoencoder needs to tell positions
# apart. The balance task adds an ensemble of five with a disagreement penalty: a single model, fitted to 20 short
# falling episodes, let the search find policies it kept up that fell within ten steps in reality.
_FIRST_FIT = {"initial_episodes": 20, "episodes_per_iteration": 4}
PIXELS_MODEL_BASED: dict[str, Any] = {
    "budget": 50,
    # a state's mirror image is not its frames' code: Pixels/Pendulum-v1 does not take Pendulum-v1's mirror_episodes
    "model_based": {**_FIRST_FIT, "ensemble_size": 5, "disagreement_penalty": 1.0, "mirror_episodes": False},
}
SWING_UP_PIXELS_MODEL_BASED: dict[str, Any] = {
    **SWING_UP_MODEL_BASED,
    "budget": 50,
    "model_based": {
        **SWING_UP_MODEL_BASED["model_based"],
        # the LSTM ensemble and explorers it was measured with (a frame's code is not the state a polynomial suits)
        "model_kind": "lstm",
        "hidden": (32,),
        "exploration_bonus": 3.0,
        "mirror_episodes": False,
        "keep_unless_improved": False,
        **_FIRST_FIT,
    },
}

# ------------------------------------------------------------------------------------------- Baxter


def _reach_model_based(both: bool, judged: bool = True) -> dict[str, Any]:
    """A model-based reach: the linear world model of the joints (the recurrent ones, fitted on the violent first
    episodes, do not carry over to a reach), six first real episodes per arm, a search of up to 100 generations in
    the model on imagined episodes of 300 steps (a reach takes about one second; 2000 imagined steps would cost seven
    times as much search), and the search settings that learn the reach model-free.

    Both arms take twelve first episodes and 60 candidates a generation: fitted on six, the model of both arms (69
    features) picks centres that fail in reality within half a second (1 of 4 seeds reached); with twelve, 9 of 10
    seeds reach, and the tenth's 20 candidates (of a 560-weight policy) all fail in the model, the search drifts
    to a centre that fails in reality within 0.2 s and stays there: with 60 it reaches after 14 real episodes.

    A run on a ``judged`` task stops once its centre reaches (real episodes are the currency: none spent past a
    centre that reaches); a dense reward's task has no verdict to stop at.
    """
    return {
        "budget": 50 if both else 30,
        "popsize": 60 if both else 20,
        "sigma_init": 0.05,
        "sigma_lr": 0.05,
        "center_lr": 0.15,
        "fitness_shaping": "centered_ranks",
        **({"stop_when_solved": True} if judged else {}),
        "model_based": {
            "model_kind": "linear",
            "initial_episodes": 12 if both else 6,
            "imagined_horizon": 300,
            "generations_per_iteration": 100,
            "patience": 20,
        },
    }


REACH_ONE_ARM_MODEL_BASED = _reach_model_based(both=False)
REACH_BOTH_ARMS_MODEL_BASED = _reach_model_based(both=True)
REACH_BOTH_ARMS_DENSE_MODEL_BASED = _reach_model_based(both=True, judged=False)
# A model-free run on a task the scripted stacker does starts from its clone (drrl.training.cloning): a tanh network of
# 128 × 128 fitted to 64 of its real episodes, then PGPE with perturbations small enough that most candidates still
# stack.
STACKING_CLONED = {
    "policy": "mlp:128,128",
    "demonstrations": 64,
    "popsize": 8,
    "budget": 128,
    "sigma_init": 0.002,
    "center_lr": 0.002,
    "eval_episodes": 20,
}

# ------------------------------------------------------------------------------------------- Gymnasium's envs

# −145.4 over 50 fresh episodes after 51,200 episodes (33 s with EnvPool); PGPE with the same policy stayed below
# −800: its one episode a candidate from random starts is too noisy to rank swing-up policies. An attempt of 100
# generations reaches −200 in 5 of 10 seeds with σ₀ 0.5, 15 of 20 with 1.0; the others settle on a policy that
# spins the pendulum and stay there however long they run. So up to 8 attempts, each from a new random centre, until
# one ends at −200 or better.
PENDULUM = {
    "search": "cmaes",
    "policy": "mlp:16",
    "popsize": 64,
    "episodes_per_candidate": 8,
    "sigma_init": 1.0,
    "restart_every": 100,
    "budget": 409600,
}
# Imagined episodes paid by the reward in closed form (drrl.envs.gymnasium_tasks), the model-free run's CMA-ES on a
# tanh MLP, three times the default generations in the model (40 reached −200 within 30 real episodes in 1 of 3
# seeds, 120 in 3 of 5), and the model fitted to every episode's mirror image too (then a median of 10 real
# episodes).
PENDULUM_MODEL_BASED = {
    "search": "cmaes",
    "policy": "mlp:16",
    "sigma_init": 0.5,
    "budget": 30,
    "model_based": {"generations_per_iteration": 120, "patience": 120, "mirror_episodes": True},
}
# Hopper pays 1 a step for staying up, 1,000 for a hopper that only stays up all episode: told of it, the defaults
# ended at 1,333. Taken off every training step, as Augmented Random Search does (Mania et al. 2018, its "shift"),
# seeds 0-2 reached 3,032, 3,323 and 2,928 in 3,200 episodes. Not a rule for every locomotion task: Walker2d-v5 with
# the same shift learned to fall at once (4.3; 2,023 without).
HOPPER = {"reward_shift": 1.0}
# One random start an episode ranks MountainCar-v0's candidates poorly: with one episode each, seed 0's best centre
# came at generation 10 (-115.5 on fresh episodes) and none later beat it in 32,000 episodes; with ten each, seeds
# 0-4 solved it (-106.6 to -108.3 on fresh episodes) in 8-12 s.
MOUNTAIN_CAR = {"episodes_per_candidate": 10, "budget": 32000}
# 3,200 episodes ended at 45.4 (seed 0); a centre first reached 200 after 4,544, and measured centres swing between
# about 110 and 280 from there: 32,000 episodes (4 minutes) leave one measured at 283, 273.5 on fresh episodes.
LUNAR_LANDER_CONTINUOUS = {"budget": 32000}
# The runners climb on past the default 3,200 episodes (seed 0 with EnvPool: HalfCheetah-v5 3,782 in 4 minutes,
# Walker2d-v5 2,569 in 9), so they get the episodes that fit in about 20 minutes on one core: HalfCheetah-v5 6,421
# after 14,400 (16 minutes), Walker2d-v5 2,866 after 6,400, short of 3,000 (taking half its alive bonus off every
# step, as Hopper's whole, gave 2,035).
HALF_CHEETAH = {"budget": 14400}
WALKER = {"budget": 6400}
# A linear arm ends near -36 (3,200 or 16,000 episodes); a tanh MLP at -31.5 after 16,000, -29.7 after 48,000
# (12 minutes, seed 0).
PUSHER = {"policy": "mlp:32", "budget": 48000}
# Once every candidate holds the poles up, the ranks still tell tiny differences in the distance and velocity terms
# apart, and ClipUp's full steps on them carry the centre off to policies that fall from the edge of the reset noise
# (measured centres of 9,360 sliding back to 6,200-9,175 within tens to hundreds of generations). A quarter of the
# default step, three times the episodes for the slower climb, and an end before that drift, once two measured
# centres in a row are solved (the first one at the level may be fragile).
INVERTED_DOUBLE_PENDULUM = {"center_lr": 0.005, "budget": 9600, "stop_when_solved": True, "solved_in_a_row": 2}
# A linear policy ends near -6.8: the torques that bring the fingertip to the target depend on the arm's angles
# times the fingertip's offset, which a tanh MLP can form and a linear map cannot. One random target an episode ranks
# candidates poorly, so 8 episodes each. The MLP climbs slowly: -5.2 on fresh episodes after 204,800 episodes, -4.7
# after 409,600 (8 to 10 minutes with EnvPool). Its centre is measured on 200 episodes (the best of many 50-episode
# measurements is chosen partly by luck), within a tenth of the run's steps.
REACHER = {
    "policy": "mlp:32",
    "popsize": 32,
    "episodes_per_candidate": 8,
    "budget": 409600,
    "eval_episodes": 200,
    "eval_share": 0.1,
}
# Imagined episodes paid by Reacher's reward and control cost in closed form, its fingertip recomputed from the
# predicted joint angles (a learned reward gave -67 to -104). The arm's state is its observation, so an ensemble of
# feed-forward models. A tanh MLP policy, searched as the model-free one that comes nearest -5, measured centres of
# -5 or better after 116 and 88 real episodes (seeds 0, 1); a linear one stays near -7.
REACHER_MODEL_BASED = {
    "policy": "mlp:32",
    "popsize": 32,
    "episodes_per_candidate": 8,
    "sigma_init": 0.025,
    "center_lr": 0.02,
    "budget": 160,
    "model_based": {
        "model_kind": "mlp",
        "hidden": [64],
        "ensemble_size": 5,
        "generations_per_iteration": 200,
        "patience": 200,
    },
}

# ------------------------------------------------------------------------------------------- the tables

PRESETS: dict[str, dict[str, Any]] = {
    "gymnasium": GYMNASIUM,
    "model-based": MODEL_BASED,
    "reinforce": REINFORCE,
    "enac": ENAC,
    "no time limit": UNLIMITED_EPISODE_CUT,
    "swing-up": SWING_UP,
    "swing-up model-based": SWING_UP_MODEL_BASED,
    "partially observed": PARTIALLY_OBSERVED,
    "pixels model-based": PIXELS_MODEL_BASED,
    "swing-up pixels model-based": SWING_UP_PIXELS_MODEL_BASED,
    "reach one arm model-based": REACH_ONE_ARM_MODEL_BASED,
    "reach both arms model-based": REACH_BOTH_ARMS_MODEL_BASED,
    "reach both arms, dense reward, model-based": REACH_BOTH_ARMS_DENSE_MODEL_BASED,
    "stacking cloned": STACKING_CLONED,
    "Pendulum-v1": PENDULUM,
    "Pendulum-v1 model-based": PENDULUM_MODEL_BASED,
    "Hopper-v5": HOPPER,
    "MountainCar-v0": MOUNTAIN_CAR,
    "HalfCheetah-v5": HALF_CHEETAH,
    "Walker2d-v5": WALKER,
    "Pusher-v5": PUSHER,
    "LunarLanderContinuous-v3": LUNAR_LANDER_CONTINUOUS,
    "InvertedDoublePendulum-v5": INVERTED_DOUBLE_PENDULUM,
    "Reacher-v5": REACHER,
    "Reacher-v5 model-based": REACHER_MODEL_BASED,
}
_ONE_ARM = ("Right", "RightRandom", "RightStandIn", "RightTargets")
_BOTH_ARMS = ("", "Targets")
_BOTH_ARMS_DENSE = ("Dense", "DenseTargets")
_CLONABLE = ("EndPoint", "RandomEndPoint", "3EndPoint", "3RandomEndPoint", "DenseEndPoint")
# env id -> {"model-free": preset, "model-based": preset}: the task's own
TASKS: dict[str, dict[str, str]] = {
    "drrl/CartPoleSwingUp-v0": {"model-free": "swing-up", "model-based": "swing-up model-based"},
    "drrl/CartPolePO-v0": {"model-free": "partially observed"},
    "drrl/CartPolePixels-v0": {"model-based": "pixels model-based"},
    "drrl/CartPoleSwingUpPixels-v0": {"model-based": "swing-up pixels model-based"},
    **{f"drrl/BaxterReach{arms}-v0": {"model-based": "reach one arm model-based"} for arms in _ONE_ARM},
    **{f"drrl/BaxterReach{arms}-v0": {"model-based": "reach both arms model-based"} for arms in _BOTH_ARMS},
    **{
        f"drrl/BaxterReach{arms}-v0": {"model-based": "reach both arms, dense reward, model-based"}
        for arms in _BOTH_ARMS_DENSE
    },
    **{f"drrl/BaxterStack{task}-v0": {"model-free": "stacking cloned"} for task in _CLONABLE},
    "Pendulum-v1": {"model-free": "Pendulum-v1", "model-based": "Pendulum-v1 model-based"},
    "Hopper-v5": {"model-free": "Hopper-v5"},
    "MountainCar-v0": {"model-free": "MountainCar-v0"},
    "HalfCheetah-v5": {"model-free": "HalfCheetah-v5"},
    "Walker2d-v5": {"model-free": "Walker2d-v5"},
    "Pusher-v5": {"model-free": "Pusher-v5"},
    "LunarLanderContinuous-v3": {"model-free": "LunarLanderContinuous-v3"},
    "InvertedDoublePendulum-v5": {"model-free": "InvertedDoublePendulum-v5"},
    "Reacher-v5": {"model-free": "Reacher-v5", "model-based": "Reacher-v5 model-based"},
}
# Tasks whose runs are model-based unless told otherwise (--model-free): the swing-up (solved after a median of 8 real
# episodes model-based, 36,000 model-free), the reaches that learn model-based (in 6-14 real episodes; both arms
# through the joint-target controller after 20, the stand-in robot from scratch after 28, seed 0) where model-free
# PGPE with their defaults fails every episode, and the tasks seen as frames (and any Pixels/ID), which only a
# model-based run's encoder lets a policy read. Not the one-arm joint-target reach (model-based, seed 0 never reached
# in 30 real episodes) nor the dense rewards' (no verdict to tell).
MODEL_BASED_TASKS = {
    "drrl/CartPoleSwingUp-v0",
    "drrl/BaxterReach-v0",
    "drrl/BaxterReachTargets-v0",
    "drrl/BaxterReachRight-v0",
    "drrl/BaxterReachRightRandom-v0",
    "drrl/BaxterReachRightStandIn-v0",
    "drrl/CartPolePixels-v0",
    "drrl/CartPoleSwingUpPixels-v0",
}
# Tasks no method of drrl learns yet, each with the task that comes closest and how: stacking with joint-velocity
# actions, where PGPE from nothing built no stack (BENCHMARKS.md) and no scripted demonstrator drives the joints;
# through the end-point controller, cloned from the stacker's demonstrations, the same stack stands in 92-100 % of
# episodes. One arm through the joint-target controller: model-free and model-based runs (seed 0, 1,000 and 30 real
# episodes) never held the target, the same reach with velocity actions does after 10.
_STACKER = "the same task through the end-point controller, cloned from the scripted stacker's demonstrations"
CLOSEST: dict[str, tuple[str, str]] = {
    **{
        f"drrl/BaxterStack{task}-v0": (f"baxter-stack{alias}-end-point", _STACKER)
        for task, alias in (("", ""), ("Random", "-random"), ("3", "3"), ("3Random", "3-random"), ("Dense", "-dense"))
    },
    "drrl/BaxterReachRightTargets-v0": ("baxter-reach-right", "the same reach with velocity actions, model-based"),
}
PIXELS = "Pixels/"  # an env seen through its camera (drrl.envs.rendered)


def task_preset(env: str, kind: str) -> str | None:
    """The name of the env's own preset for a run of ``kind`` (model-free or model-based), if it has one."""
    return TASKS.get(_env_id(env) or "", {}).get(kind)


def not_learned(env: object) -> str | None:
    """What to tell a user before a run on a task no method of drrl learns yet; None for the others."""
    if (env_id := _env_id(env) or "") not in CLOSEST:
        return None
    closest, how = CLOSEST[env_id]
    return f"no method of drrl learns {env} yet; what comes closest is {closest}, {how} (drrl train {closest})"


def default_kind(env: object) -> str:
    """The kind of run (model-free or model-based) ``drrl train`` makes on ``env`` unless told which."""
    env_id = _env_id(env) or ""
    return "model-based" if env_id in MODEL_BASED_TASKS or env_id.startswith(PIXELS) else "model-free"


def presets_for(env: object, kind: str, search: object = None) -> list[tuple[str, dict]]:
    """The presets a run of ``kind`` on ``env`` with ``search`` starts from, in the order they apply (later over
    earlier), as (name, flat settings); none for a name that is no env (the env's own check says why)."""
    env_id = _env_id(env)
    if env_id is None:
        return []
    if kind == "action-space":
        return [(str(search), PRESETS[str(search)])]
    names = ["model-based"] if kind == "model-based" else [] if _own(env_id) else ["gymnasium"]
    return [(name, PRESETS[name]) for name in [*names, *_task_presets(env_id, kind)]]


def _task_presets(env_id: str, kind: str) -> list[str]:
    """The env's own presets for a run of ``kind``: an env seen through its camera (``Pixels/ID``, model-based) has
    its inner env's, then the pixels' own."""
    if env_id.startswith(PIXELS):
        inner = env_id.removeprefix(PIXELS)
        return [*_task_presets(inner, kind), "pixels model-based"] if kind == "model-based" else []
    cut = [] if _own(env_id) or _time_limited(env_id) else ["no time limit"]
    own = task_preset(env_id, kind)
    return cut + ([own] if own else [])


def task_settings(env: object, kind: str) -> dict:
    """The settings the env's own presets give a run of ``kind`` (model-free or model-based), merged; none where it has
    none (the general presets aside)."""
    env_id = _env_id(env)
    settings: dict = {}
    for name in [] if env_id is None else _task_presets(env_id, kind):
        preset = PRESETS[name]
        table = {**settings.get("model_based", {}), **preset.get("model_based", {})}
        settings.update(preset)
        if table:
            settings["model_based"] = table
    return settings


def _env_id(env: object) -> str | None:
    if not isinstance(env, str):
        return None
    try:
        return lookup(env).env_id
    except ValueError:
        return None


def _own(env_id: str) -> bool:
    return is_own(env_id)


def _time_limited(env_id: str) -> bool:
    return bool(gymnasium.spec(env_id).max_episode_steps)
