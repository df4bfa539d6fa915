"""The UR5e robot model: shipped URDF kinematics, default limits and collision shapes.

Every capsule is a segment ``a -> b`` with a radius, in the frame of the link that carries it:
the URDF link frame of the shipped model (:file:`planner/data/ur5e.urdf`), i.e. the frame of
the joint that moves the link (z = that joint's axis, origin = that joint's origin; the
standard-DH frame i-1 turned by q_i). ``base`` is the fixed robot base frame. Metres.

Source of the numbers: UR's published collision meshes ``meshes/ur5e/collision/*.stl`` of
``UniversalRobots/Universal_Robots_ROS2_Description`` (release 2.4.5, commit 2221ec0),
placed with that package's ``ur_macro.xacro`` collision origins and
``config/ur5e/default_kinematics.yaml`` (its ``base_link`` chain reproduces the DH flange pose
to 1e-15 m), were expressed in the link frames above. Each joint housing is the
minimum-volume capsule with a fixed axis that encloses the mesh vertices of that housing
(endpoints rounded to 1 mm, radius rounded up to 1 mm). The two long tubes lie on the
measured lateral offsets (``shoulder_offset`` 0.138 m, ``elbow_offset`` 0.007 m of
``config/ur5e/physical_parameters.yaml``); the upper-arm tube radius is that file's
``upper_arm_radius`` (0.054 m, manually measured by UR), the forearm tube radius 0.049 m is
the smallest that encloses the forearm mesh's taper towards the elbow (the file gives 0.040 m
at the slim end). The wrist_3 link (a short disc under the flange) is a box instead: a
capsule long enough to hold its rim would bulge 29 mm past the flange face, into the space
between flange and mirror the beam uses; the box is the mesh's bounding box (rounded out to
0.5 mm) and ends at the flange face. The union of each link's shapes encloses every vertex
of its mesh.
"""

from __future__ import annotations

from planner.model.collision import BoxSpec, CapsuleSpec, CollisionShapes

#: link names in chain order; index 0 is the fixed base, index i moves with joint i
UR5E_LINKS = (
    "base",
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)


UR5E_CAPSULES: tuple[CapsuleSpec, ...] = (
    CapsuleSpec("base", 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.05), 0.076),
    CapsuleSpec("shoulder", 1, (0.0, -0.013, 0.145), (0.0, -0.013, 0.162), 0.085),
    CapsuleSpec("upper_arm_shoulder", 2, (0.0, 0.0, 0.09), (0.0, 0.0, 0.182), 0.061),
    CapsuleSpec("upper_arm", 2, (0.0, 0.0, 0.138), (-0.425, 0.0, 0.138), 0.054),
    CapsuleSpec("upper_arm_elbow", 2, (-0.425, 0.0, 0.076), (-0.425, 0.0, 0.182), 0.061),
    CapsuleSpec("forearm_elbow", 3, (0.0, 0.0, -0.01), (0.0, 0.0, 0.03), 0.066),
    CapsuleSpec("forearm", 3, (0.0, 0.0, 0.007), (-0.3922, 0.0, 0.007), 0.049),
    CapsuleSpec("forearm_wrist", 3, (-0.3922, 0.0, -0.027), (-0.3922, 0.0, 0.048), 0.040),
    CapsuleSpec("wrist_1", 4, (0.0, 0.0, 0.111), (0.0, 0.0, 0.133), 0.066),
    CapsuleSpec("wrist_2", 5, (0.0, -0.009, 0.096), (0.0, 0.013, 0.096), 0.058),
)


UR5E_BOXES: tuple[BoxSpec, ...] = (
    BoxSpec("wrist_3", 6, (0.0, -0.003, 0.0766), (0.076, 0.082, 0.0462)),
)

#: link shapes never checked against each other: their envelopes sit a few mm apart (or
#: overlap) at every configuration although the real links cannot meet (wrist_1 and wrist_3
#: only turn about each other through wrist_2)
UR5E_SELF_EXCLUDED = frozenset({("wrist_1", "wrist_3")})


UR5E_SHAPES = CollisionShapes(UR5E_LINKS, UR5E_CAPSULES, UR5E_BOXES, UR5E_SELF_EXCLUDED)
"""The UR5e's link shapes for :mod:`planner.model.robots`."""
