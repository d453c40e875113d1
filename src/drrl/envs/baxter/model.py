"""drrl's own MuJoCo model of Baxter (thesis 5.2): torso, two 7-joint arms, a table in front.

Numbers, not meshes. The arms' kinematics are Rethink Robotics' URDF joint origins (rpy = fixed-axis x-y-z), which
put the gripper end-point where the Denavit–Hartenberg table of ../shared/reference/baxter/README.md does (tests
check it to 1 mm); position and velocity limits, efforts, the joint damping 0.7 and the link masses are the URDF's.
Everything else is drrl's simplification:

- each link is one or two capsules (radius 4–6 cm, after the URDF's collision cylinders) carrying the link's mass,
  so the inertia is that of the capsules, not the URDF's measured tensors;
- the torso, head, pedestal, floor and table are boxes and capsules; the head does not move;
- an arm collides with the scene and with the other arm, never with itself (its neighbouring links overlap at the
  joints, as the real links nest);
- each joint has a MuJoCo ``velocity`` actuator (kv = 50, force limited to the joint's effort) and the arm bodies
  have ``gravcomp="1"``, as Baxter's controller compensates gravity; the ``implicitfast`` integrator treats kv
  implicitly, which keeps a 0.002 s timestep stable. The joint damping 0.7 makes a held command lag by
  0.7 / 50.7 = 1.4 % (0.493 rad/s for 0.5);
- each joint has an armature (rotor inertia) of 0.05 kg·m², our value, not Rethink's: the light wrist links need it.
  Without it, whenever the effort limit clips an actuator's force the implicit step no longer damps the link, and
  w2 oscillated at ±13 rad/s under a 0.5 rad/s command;
- the joint stops are stiffer than MuJoCo's default (constraint time constant 0.005 s instead of 0.02 s): a joint
  driven into its stop at full speed goes at most 0.012 rad beyond it instead of 0.034 rad.

Coordinates are the robot's base frame (x forward, y left, z up, metres). An arm left out of ``moving_arms`` is
still drawn and collided with, rigid in its neutral pose, so the one-arm robot looks and collides like Baxter.
"""

from __future__ import annotations

import ctypes.util
import os
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache

import numpy as np

SIDES = ("right", "left")
TIMESTEP = 0.002  # seconds per physics step
VELOCITY_GAIN = 50.0  # kv of the velocity actuators, N·m per rad/s
JOINT_DAMPING = 0.7  # the URDF's, N·m per rad/s
ARMATURE = 0.05  # rotor inertia added to each joint, kg·m² (see the module's docstring)
LIMIT_TIME_CONSTANT = 0.005  # seconds: stiff joint stops (see the module's docstring)
END_POINT_OFFSET = 0.025  # the gripper end-point, metres beyond the hand frame along its z


@dataclass(frozen=True)
class Joint:
    """One arm joint, the link it moves and that link's simplified shape."""

    name: str
    origin: tuple[float, float, float]  # in the parent link's frame (URDF)
    rpy: tuple[float, float, float]
    lower: float  # position limits, rad
    upper: float
    max_velocity: float  # rad/s
    max_effort: float  # N·m
    mass: float  # of the link the joint moves, kg
    capsules: tuple[tuple[tuple[float, ...], float], ...]  # (fromto in the link's frame, radius)


HALF_PI = np.pi / 2
ARM = (
    Joint(
        "s0",
        (0.055695, 0, 0.011038),
        (0, 0, 0),
        -1.70167993878,
        1.70167993878,
        1.5,
        50.0,
        5.70044,
        (((0, 0, 0.08, 0, 0, 0.27035), 0.06), ((0, 0, 0.27035, 0.069, 0, 0.27035), 0.06)),
    ),
    Joint(
        "s1",
        (0.069, 0, 0.27035),
        (-HALF_PI, 0, 0),
        -2.147,
        1.047,
        1.5,
        100.0,
        3.22698,
        (((0, 0, 0, 0.102, 0, 0), 0.06),),
    ),
    Joint(
        "e0",
        (0.102, 0, 0),
        (HALF_PI, 0, HALF_PI),
        -3.05417993878,
        3.05417993878,
        1.5,
        50.0,
        4.31272,
        (((0, 0, 0, 0, 0, 0.26242), 0.06), ((0, 0, 0.26242, 0.069, 0, 0.26242), 0.06)),
    ),
    Joint(
        "e1",
        (0.069, 0, 0.26242),
        (-HALF_PI, -HALF_PI, 0),
        -0.05,
        2.618,
        1.5,
        50.0,
        2.07206,
        (((0, 0, 0, 0.10359, 0, 0), 0.06),),
    ),
    Joint(
        "w0",
        (0.10359, 0, 0),
        (HALF_PI, 0, HALF_PI),
        -3.059,
        3.059,
        4.0,
        15.0,
        2.24665,
        (((0, 0, 0, 0, 0, 0.2707), 0.05), ((0, 0, 0.2707, 0.01, 0, 0.2707), 0.05)),
    ),
    Joint(
        "w1",
        (0.01, 0, 0.2707),
        (-HALF_PI, -HALF_PI, 0),
        -1.57079632679,
        2.094,
        4.0,
        15.0,
        1.60979,
        (((0, 0, 0, 0.115975, 0, 0), 0.05),),
    ),
    Joint(
        "w2",
        (0.115975, 0, 0),
        (HALF_PI, 0, HALF_PI),
        -3.059,
        3.059,
        4.0,
        15.0,
        0.35093,
        (((0, 0, 0, 0, 0, 0.11355), 0.045),),
    ),
)
HAND = (0.0, 0.0, 0.11355)  # the hand frame in the last link's frame
HAND_MASS = 0.19125
HAND_CAPSULE = ((0, 0, 0, 0, 0, END_POINT_OFFSET), 0.04)
TORSO_MASS = 35.336  # static: it never moves, so its mass plays no part
TARGET_RADIUS = 0.05  # the target markers are drawn as spheres of the reach tolerance


def arm_mount(side: str) -> tuple[tuple[float, float, float], float]:
    """The arm mount in the torso's frame: position and yaw (rad). The right arm is the left one mirrored in y."""
    sign = -1.0 if side == "right" else 1.0
    return (0.024645, sign * 0.219645, 0.118588), sign * 0.7854


# The neutral pose (rad): upper arms level, elbows and wrists bent, hands out to the sides above the table, far from
# every joint limit (close to the pose Baxter's SDK calls neutral). Episodes start near it.
NEUTRAL = {"s0": 0.0, "s1": -0.55, "e0": 0.0, "e1": 0.75, "w0": 0.0, "w1": 1.26, "w2": 0.0}
MIRRORED = {"s0", "e0", "w0", "w2"}  # roll joints: the left arm's mirror pose negates them


def neutral_pose(side: str) -> np.ndarray:
    """The neutral joint angles (7,) of one arm; the two arms' poses are mirror images."""
    sign = -1.0 if side == "left" else 1.0
    return np.array([NEUTRAL[j.name] * (sign if j.name in MIRRORED else 1.0) for j in ARM])


# The scene (base frame): table top 0.20 m below the torso origin, the floor 0.93 m below it.
TABLE_TOP = -0.20
TABLE = {"pos": (0.90, 0.0, TABLE_TOP - 0.02), "size": (0.35, 0.75, 0.02)}  # a box, half-sizes
FLOOR_HEIGHT = -0.93

# Collision classes: the scene collides with both arms, each arm with the other; an arm's own links never collide.
SCENE, RIGHT_ARM, LEFT_ARM = 1, 2, 4
ARM_BITS = {"right": RIGHT_ARM, "left": LEFT_ARM}

COLOURS = {
    "arm": "0.55 0.1 0.1 1",
    "joint": "0.15 0.15 0.15 1",
    "torso": "0.25 0.25 0.28 1",
    "table": "0.6 0.45 0.3 1",
    "target": "0.2 0.9 0.3 0.6",
    "floor": "0.85 0.85 0.85 1",
}


def _vec(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _add(parent: ET.Element, tag: str, **attributes) -> ET.Element:
    return ET.SubElement(parent, tag, {key: str(value) for key, value in attributes.items()})


def _scene_geom(parent: ET.Element, name: str, colour: str = "torso", **attributes) -> None:
    """A static geom that both arms collide with."""
    _add(parent, "geom", name=name, contype=SCENE, conaffinity=RIGHT_ARM | LEFT_ARM, rgba=COLOURS[colour], **attributes)


def _table_legs(world: ET.Element) -> None:
    """Four legs, drawn only: nothing can reach under the table top without touching it first."""
    (x, y, z), (dx, dy, dz) = TABLE["pos"], TABLE["size"]
    for sx in (-1, 1):
        for sy in (-1, 1):
            leg = (x + sx * (dx - 0.05), y + sy * (dy - 0.05))
            _add(
                world,
                "geom",
                name=f"table_leg_{sx}{sy}".replace("-", "m"),
                contype=0,
                conaffinity=0,
                fromto=_vec((*leg, FLOOR_HEIGHT, *leg, z - dz)),
                size=0.03,
                rgba=COLOURS["table"],
            )


def _arm(torso: ET.Element, side: str, moving: bool) -> None:
    """One arm as a chain of bodies; with ``moving`` False it has no joints and holds its neutral pose."""
    mount, yaw = arm_mount(side)
    bits = ARM_BITS[side]
    other = LEFT_ARM if side == "right" else RIGHT_ARM
    parent = _add(torso, "body", name=f"{side}_arm_mount", pos=_vec(mount), euler=_vec((0, 0, yaw)))
    for joint, angle in zip(ARM, neutral_pose(side), strict=True):
        body = _add(
            parent, "body", name=f"{side}_{joint.name}", pos=_vec(joint.origin), euler=_vec(joint.rpy), gravcomp=1
        )
        if moving:
            _add(body, "joint", name=f"{side}_{joint.name}", range=_vec((joint.lower, joint.upper)))
        else:  # the joint's neutral angle as a fixed rotation about its axis
            body = _add(body, "body", name=f"{side}_{joint.name}_rigid", euler=_vec((0, 0, angle)))
        length = sum(np.linalg.norm(np.subtract(fromto[3:], fromto[:3])) for fromto, _ in joint.capsules)
        for k, (fromto, radius) in enumerate(joint.capsules):
            share = np.linalg.norm(np.subtract(fromto[3:], fromto[:3])) / length
            _add(
                body,
                "geom",
                name=f"{side}_{joint.name}_link{k}",
                fromto=_vec(fromto),
                size=radius,
                mass=f"{joint.mass * share:.9g}",
                contype=bits,
                conaffinity=SCENE | other,
                rgba=COLOURS["arm"],
            )
        parent = body
    hand = _add(parent, "body", name=f"{side}_hand", pos=_vec(HAND), gravcomp=1)
    fromto, radius = HAND_CAPSULE
    _add(
        hand,
        "geom",
        name=f"{side}_hand",
        fromto=_vec(fromto),
        size=radius,
        mass=HAND_MASS,
        contype=bits,
        conaffinity=SCENE | other,
        rgba=COLOURS["joint"],
    )
    _add(hand, "site", name=f"{side}_end_point", pos=_vec((0, 0, END_POINT_OFFSET)), size=0.01, rgba="1 1 0 1")


def _actuators(root: ET.Element, moving_arms: tuple[str, ...]) -> None:
    actuators = _add(root, "actuator")
    for side in moving_arms:
        for joint in ARM:
            name = f"{side}_{joint.name}"
            _add(
                actuators,
                "velocity",
                name=name,
                joint=name,
                kv=VELOCITY_GAIN,
                ctrlrange=_vec((-joint.max_velocity, joint.max_velocity)),
                forcerange=_vec((-joint.max_effort, joint.max_effort)),
            )


def baxter_xml(moving_arms: tuple[str, ...] = SIDES) -> str:
    """The MJCF text of Baxter with ``moving_arms`` jointed and actuated, one target marker per moving arm."""
    root = baxter_tree(moving_arms)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def baxter_tree(moving_arms: tuple[str, ...] = SIDES, target_markers: bool = True) -> ET.Element:
    """``baxter_xml``'s MJCF as an element tree, for scenes built on it (``drrl.envs.baxter.grasping``)."""
    unknown = set(moving_arms) - set(SIDES)
    if unknown or not moving_arms or len(set(moving_arms)) != len(moving_arms):
        raise ValueError(f"moving_arms must be distinct sides among {SIDES}, got {moving_arms!r}")
    root = ET.Element("mujoco", model="drrl_baxter")
    _add(root, "compiler", angle="radian", eulerseq="XYZ", autolimits="true")  # XYZ: fixed axes, as URDF rpy
    _add(root, "option", timestep=TIMESTEP, integrator="implicitfast")
    visual = _add(root, "visual")
    _add(visual, "global", offwidth=1280, offheight=960)
    assets = _add(root, "asset")
    _add(
        assets,
        "texture",
        type="skybox",
        builtin="gradient",
        rgb1="0.55 0.65 0.8",
        rgb2="0.1 0.1 0.15",
        width=64,
        height=64,
    )
    default = _add(root, "default")
    _add(default, "joint", damping=JOINT_DAMPING, armature=ARMATURE, solreflimit=f"{LIMIT_TIME_CONSTANT} 1")
    _add(default, "geom", type="capsule")
    world = _add(root, "worldbody")
    _add(world, "light", name="top", pos="0.5 0 2.5", dir="0 0 -1", diffuse="0.6 0.6 0.6")
    _add(world, "light", name="front", pos="3 -1 2", dir="-0.8 0.3 -0.5", diffuse="0.5 0.5 0.5", directional="true")
    _scene_geom(world, "floor", colour="floor", type="plane", pos=_vec((0, 0, FLOOR_HEIGHT)), size="3 3 0.1")
    _scene_geom(world, "table", colour="table", type="box", pos=_vec(TABLE["pos"]), size=_vec(TABLE["size"]))
    _table_legs(world)
    torso = _add(world, "body", name="torso")
    _scene_geom(torso, "torso", type="box", pos="-0.03 0 -0.20", size="0.13 0.16 0.30", mass=TORSO_MASS)
    _scene_geom(torso, "neck", fromto="0 0 0.10 0.05 0 0.62", size=0.05)
    _scene_geom(torso, "head", type="box", pos="0.16 0 0.69", size="0.02 0.14 0.10")
    _scene_geom(torso, "pedestal", fromto=_vec((-0.03, 0, FLOOR_HEIGHT, -0.03, 0, -0.5)), size=0.12)
    for side in SIDES:
        _arm(torso, side, moving=side in moving_arms)
    for side in moving_arms if target_markers else ():
        target = _add(world, "body", name=f"{side}_target", mocap="true")
        _add(
            target,
            "geom",
            name=f"{side}_target",
            type="sphere",
            size=TARGET_RADIUS,
            contype=0,
            conaffinity=0,
            rgba=COLOURS["target"],
        )
    _actuators(root, moving_arms)
    return root


def import_mujoco():
    """The ``mujoco`` module, imported when a Baxter is first made (not when drrl is imported).

    MuJoCo picks its OpenGL backend when first imported, and fails to import if that backend's library is missing.
    Unless ``MUJOCO_GL`` is set, we pick a headless one on Linux (``headless_gl``).
    """
    if "mujoco" not in sys.modules and "MUJOCO_GL" not in os.environ and sys.platform.startswith("linux"):
        os.environ["MUJOCO_GL"] = headless_gl()
    try:
        import mujoco
    except (ImportError, AttributeError, OSError) as error:  # AttributeError: PyOpenGL without its library
        raise ImportError(
            f"MuJoCo failed to import with MUJOCO_GL={os.environ.get('MUJOCO_GL')}: {error!r}. Set "
            "MUJOCO_GL=egl (Debian: libegl1 libegl-mesa0), osmesa (libosmesa6) or disable (physics "
            "without rendering)"
        ) from error
    return mujoco


def headless_gl() -> str:
    """EGL if libEGL is found (Mesa's llvmpipe renders on CPU-only machines), else OSMesa if libOSMesa is, else
    "disable": the physics runs and rendering raises a clear error."""
    for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(library):
            return backend
    return "disable"


@cache
def load_model(moving_arms: tuple[str, ...] = SIDES):
    """The compiled ``mujoco.MjModel`` (cached: treat it as read-only)."""
    return import_mujoco().MjModel.from_xml_string(baxter_xml(moving_arms))
