"""Baxter with its electric parallel grippers and wooden blocks on the table: the scene of the stacking tasks (5.2).

The thesis sets Baxter to "use its arms and gripper to learn to perform a certain wood stacking task" (5.2). This
scene is drrl's model of Baxter (``drrl.envs.baxter.model``) with, on every hand, Rethink Robotics' electric
parallel gripper, and ``blocks`` pine cubes on the table. Numbers and where they come from:

- finger travel 20.833 mm per finger, both fingers moved together (one the other's mirror), and 20 N of force per
  finger: the prismatic finger joints of Rethink's gripper description (``rethink_electric_gripper.xacro`` in
  RethinkRobotics/baxter_common: limits 0–0.020833 m, effort 20, the second finger mimicking the first; damping
  0.7 N·s/m); the gripper's body 2.5 cm beyond the hand frame and the fingers 2 cm beyond that, its mass 0.3 kg
  and its body a cylinder of radius 2.9 cm, 10 cm across, are the same file's;
- open and shut within a second (Rethink's description of the gripper, Machine Design, 2012): the servo closes at
  up to 4 cm/s (its damping), 0.5 s for the whole stroke;
- fingers 6 cm long, 2 cm wide, their pads 72 mm apart when open, so 30 mm when closed: our choice among the
  finger lengths and slot positions Rethink offers, for blocks of 4 cm;
- blocks 4 cm a side of pine, 500 kg/m³ (pine is 350–670 kg/m³), 32 g each.

Beyond the URDF: the two fingers are one actuated opening (a fixed tendon, their mean closing, and an equality
holding them equal), driven by a position servo whose command is the opening as a fraction of full (0 closed,
1 open, as Baxter's gripper takes 0–100 %), force-limited to 20 N a finger; each finger carries 1 kg of armature,
the reflected inertia of a geared drive (ours), which keeps the stiff servo stable at 0.002 s. Contacts use
MuJoCo's elliptic friction cones with ``impratio`` 10, torsional friction at the pads and friction 1 between pads
and wood (rubber on wood), 0.5 between wood and wood or table: a grasp then holds a block without creeping.

Failures (reward 5.10's rule on this scene) are read from contact sensors: an arm, its gripper included, touching
the table, the floor, the body or the other arm. An arm or a finger touching a block is not a failure. Each
finger has a sensor per block, which says what the gripper holds.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import cache

from drrl.envs.baxter.model import (
    ARM_BITS,
    END_POINT_OFFSET,
    LEFT_ARM,
    RIGHT_ARM,
    SCENE,
    SIDES,
    TABLE_TOP,
    _add,
    _vec,
    baxter_tree,
    import_mujoco,
)

FINGER_TRAVEL = 0.020833  # m per finger (Rethink's URDF)
GRIP_FORCE = 20.0  # N per finger (Rethink's URDF effort)
GRIPPER_BASE = END_POINT_OFFSET  # m beyond the hand frame: the gripper's body (Rethink's URDF)
FINGER_BASE = GRIPPER_BASE + 0.02  # m beyond the hand frame: where the fingers are mounted (Rethink's URDF)
GRIPPER_MASS = 0.3  # kg (Rethink's URDF)
FINGER_LENGTH = 0.06  # m (ours)
FINGER_MASS = 0.02  # kg (ours)
FINGER_ARMATURE = 1.0  # kg: the drive's reflected inertia (ours)
FINGER_DAMPING = 0.7  # N·s/m (Rethink's URDF)
PAD_THICKNESS = 0.01  # m
OPEN_WIDTH = 0.072  # m between the pads, open (ours: a slot position for 4 cm blocks)
CLOSED_WIDTH = OPEN_WIDTH - 2 * FINGER_TRAVEL
GRIP_STIFFNESS = 10_000.0  # N/m of mean closing: the servo saturates at 20 N 4 mm short of its target
GRIP_DAMPING = 1_000.0  # N·s/m: 2 × 20 N / 1000 = 4 cm/s of closing at most
GRIP_POINT = FINGER_BASE + FINGER_LENGTH - 0.02  # m beyond the hand frame: a grasped block's centre, 2 cm in
PAD_TIME_CONSTANT = 0.01  # s: stiffer pad contacts than MuJoCo's 0.02: a gripped block sinks 1.5 mm into a pad, not 2.1
BLOCK_SIZE = 0.04  # m, a side
PINE_DENSITY = 500.0  # kg/m³
BLOCK = 8  # collision class of the blocks (see drrl.envs.baxter.model: SCENE 1, arms 2 and 4)
BLOCK_TOP_REST = TABLE_TOP + BLOCK_SIZE / 2  # a block's centre height lying on the table
COLOURS = {"pad": "0.1 0.1 0.1 1", "gripper": "0.5 0.1 0.1 1"}
BLOCK_COLOURS = ("0.87 0.72 0.53 1", "0.80 0.60 0.40 1", "0.93 0.80 0.62 1", "0.72 0.52 0.34 1")


def grasping_xml(moving_arms: tuple[str, ...] = ("right",), blocks: int = 2) -> str:
    """The MJCF text of Baxter with ``moving_arms`` jointed and actuated, a gripper on each hand (actuated on the
    moving arms) and ``blocks`` free blocks on the table (put in place by whoever starts an episode)."""
    if blocks < 0:
        raise ValueError(f"blocks must be ≥ 0, got {blocks}")
    root = baxter_tree(moving_arms, target_markers=False)
    _one(root, "option").attrib.update(cone="elliptic", impratio="10")
    for geom in root.iter("geom"):  # the arms push blocks, the scene holds them
        if geom.get("contype") in {str(SCENE), str(RIGHT_ARM), str(LEFT_ARM)}:
            geom.set("conaffinity", str(int(geom.get("conaffinity", "0")) | BLOCK))
    for side in SIDES:
        _gripper(_one(root, f".//body[@name='{side}_hand']"), side, moving=side in moving_arms)
    world = _one(root, "worldbody")
    for k in range(blocks):
        body = _add(world, "body", name=f"block{k}", pos=_vec((0.6, -0.3 + 0.1 * k, BLOCK_TOP_REST)))
        _add(body, "freejoint", name=f"block{k}")
        _add(
            body,
            "geom",
            name=f"block{k}",
            type="box",
            size=_vec((BLOCK_SIZE / 2,) * 3),
            density=PINE_DENSITY,
            friction="0.5 0.005 0.0001",
            condim=4,
            contype=BLOCK,
            conaffinity=SCENE | RIGHT_ARM | LEFT_ARM | BLOCK,
            rgba=BLOCK_COLOURS[k % len(BLOCK_COLOURS)],
        )
    _grip_actuators(root, moving_arms)
    _sensors(root, moving_arms, blocks)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def _one(root: ET.Element, path: str) -> ET.Element:
    element = root.find(path)
    if element is None:
        raise LookupError(f"the Baxter MJCF has no {path}")
    return element


def _gripper(hand: ET.Element, side: str, moving: bool) -> None:
    """The gripper's body across the hand and two fingers closing along the hand's y axis."""
    bits = ARM_BITS[side]
    affinity = SCENE | (LEFT_ARM if side == "right" else RIGHT_ARM) | BLOCK
    shape = {"contype": bits, "conaffinity": affinity}
    _add(
        hand,
        "geom",
        name=f"{side}_gripper",
        fromto=_vec((0, -0.05, GRIPPER_BASE, 0, 0.05, GRIPPER_BASE)),
        size=0.029,
        mass=GRIPPER_MASS,
        rgba=COLOURS["gripper"],
        **shape,
    )
    _add(hand, "site", name=f"{side}_grip", pos=_vec((0, 0, GRIP_POINT)), size=0.008, rgba="1 1 0 1")
    for finger, sign in ((1, 1.0), (2, -1.0)):
        name = f"{side}_finger{finger}"
        centre = (0, sign * (OPEN_WIDTH + PAD_THICKNESS) / 2, FINGER_BASE + FINGER_LENGTH / 2)
        body = _add(hand, "body", name=name, pos=_vec(centre), gravcomp=1)
        if moving:
            _add(
                body,
                "joint",
                name=name,
                type="slide",
                axis=_vec((0, -sign, 0)),  # positive closes
                range=_vec((0, FINGER_TRAVEL)),
                damping=FINGER_DAMPING,
                armature=FINGER_ARMATURE,
            )
        _add(
            body,
            "geom",
            name=name,
            type="box",
            size=_vec((0.01, PAD_THICKNESS / 2, FINGER_LENGTH / 2)),
            mass=FINGER_MASS,
            friction="1 0.005 0.0001",
            condim=4,
            solref=_vec((PAD_TIME_CONSTANT, 1)),
            rgba=COLOURS["pad"],
            **shape,
        )


def _grip_actuators(root: ET.Element, moving_arms: tuple[str, ...]) -> None:
    """Per moving arm: the fingers' mean closing as a tendon, the fingers held equal, and the opening servo."""
    tendons, equality, actuators = _add(root, "tendon"), _add(root, "equality"), _one(root, "actuator")
    for side in moving_arms:
        fixed = _add(tendons, "fixed", name=f"{side}_grip")
        for finger in (1, 2):
            _add(fixed, "joint", joint=f"{side}_finger{finger}", coef=0.5)
        _add(equality, "joint", joint1=f"{side}_finger2", joint2=f"{side}_finger1")
        # force = k·(travel·(1 − opening) − closing) − d·closing rate, on the mean closing
        _add(
            actuators,
            "general",
            name=f"{side}_grip",
            tendon=f"{side}_grip",
            ctrlrange="0 1",
            forcerange=_vec((-2 * GRIP_FORCE, 2 * GRIP_FORCE)),
            gainprm=_vec((-GRIP_STIFFNESS * FINGER_TRAVEL,)),
            biastype="affine",
            biasprm=_vec((GRIP_STIFFNESS * FINGER_TRAVEL, -GRIP_STIFFNESS, -GRIP_DAMPING)),
        )


def _sensors(root: ET.Element, moving_arms: tuple[str, ...], blocks: int) -> None:
    """Contact counts: failures (per arm: with the world's geoms, with the body's, with the other arm) first, then
    for each moving arm, finger and block whether they touch (``BaxterBatch.touching`` reads them in this order)."""
    sensors = _add(root, "sensor")
    for side in SIDES:
        arm = f"{side}_arm_mount"
        _add(sensors, "contact", name=f"{side}_scene", subtree1=arm, body2="world", data="found", num=1)
        _add(sensors, "contact", name=f"{side}_body", subtree1=arm, body2="torso", data="found", num=1)
    _add(sensors, "contact", name="arms", subtree1="right_arm_mount", subtree2="left_arm_mount", data="found", num=1)
    for side in moving_arms:
        for finger in (1, 2):
            for k in range(blocks):
                _add(
                    sensors,
                    "contact",
                    name=f"{side}_finger{finger}_block{k}",
                    body1=f"{side}_finger{finger}",
                    body2=f"block{k}",
                    data="found",
                    num=1,
                )


FAILURE_SENSORS = 2 * len(SIDES) + 1  # the first sensors of ``_sensors``


@cache
def load_grasping_model(moving_arms: tuple[str, ...] = ("right",), blocks: int = 2):
    """The compiled ``mujoco.MjModel`` of ``grasping_xml`` (cached: treat it as read-only)."""
    return import_mujoco().MjModel.from_xml_string(grasping_xml(moving_arms, blocks))
