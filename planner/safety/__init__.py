"""Safety geometry: collision capsules of the arms, mirror and mount blocks, scene objects
and keep-out volumes in one Pinocchio/coal world, the clearance checks built on it, the
rules the planner applies (:class:`Safety`) and the trajectory checks (world frame, metres,
radians)."""

from planner.safety.beam import (
    ApertureHit,
    beam_arm,
    beam_keep_out,
    beam_points,
    camera_lens,
    laser_return,
    target_keep_out,
)
from planner.safety.checks import (
    DEFAULT_CLEARANCE,
    Check,
    Clearance,
    all_pair_distances,
    arm_arm,
    arm_scene,
    arm_self,
    pair_clearances,
    violations,
    worst,
)
from planner.safety.geometry import PairKind, Part, PartKind, SafetyWorld
from planner.safety.model import Safety, SafetySettings, Violation
from planner.safety.shapes import Volume, box, sphere, volumes_from_scene_items
from planner.safety.sweep import SweepViolation, check_sweep
from planner.safety.trajectory import SafeMover, TrajectoryCheck, check_trajectory
from planner.safety.ur5e import (
    UR5E_BOXES,
    UR5E_CAPSULES,
    UR5E_SELF_EXCLUDED,
    BoxSpec,
    CapsuleSpec,
    MirrorBlocks,
)

__all__ = [
    "DEFAULT_CLEARANCE",
    "UR5E_BOXES",
    "UR5E_CAPSULES",
    "UR5E_SELF_EXCLUDED",
    "ApertureHit",
    "BoxSpec",
    "CapsuleSpec",
    "Check",
    "Clearance",
    "MirrorBlocks",
    "PairKind",
    "Part",
    "PartKind",
    "SafeMover",
    "Safety",
    "SafetySettings",
    "SafetyWorld",
    "SweepViolation",
    "TrajectoryCheck",
    "Violation",
    "Volume",
    "all_pair_distances",
    "arm_arm",
    "arm_scene",
    "arm_self",
    "beam_arm",
    "beam_keep_out",
    "beam_points",
    "box",
    "camera_lens",
    "check_sweep",
    "check_trajectory",
    "laser_return",
    "pair_clearances",
    "sphere",
    "target_keep_out",
    "violations",
    "volumes_from_scene_items",
    "worst",
]
