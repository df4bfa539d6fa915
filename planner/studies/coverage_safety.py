"""The product's safety rules applied to a relay of the coverage study.

A relay of the coverage study is an ordered sub-chain of the robots, its mirror hit points
and the target. It counts only when :class:`planner.safety.Safety` (the rules the planner
itself applies) finds no violation of:

- arm-arm (the chain's arms keep ``clearance`` from each other), arm-self (no two links of
  one arm touch) and arm-scene (every arm keeps ``clearance`` from the object);
- beam-arm: every beam segment keeps ``clearance`` from every arm part that it does not
  reflect on (and touches no other part of the arms it reflects on);
- keep-out (the coverage layout has no keep-out volume of its own) and the beam returning
  into the laser aperture.

The robots left out of the sub-chain are still in the cell, parked at :func:`parked_q`
(home with the shoulder turned half a turn: the arm folded away from the object). Their
collision parts (the same capsules and boxes) at that posture enter the rules as fixed
geometry: as scene objects for the chain's arms (``clearance`` kept, as arm-arm) and,
grown by ``clearance``, as keep-out volumes for the beam (so the beam keeps ``clearance``
from them too; a grown box is a little larger than the exact offset at its corners, which
errs on the safe side).

World frame, metres, radians throughout.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from planner.model.system import Robot, System
from planner.model.transforms import Array, make_T
from planner.safety import (
    DEFAULT_CLEARANCE,
    Safety,
    SafetySettings,
    SafetyWorld,
    Violation,
    Volume,
    box,
    sphere,
)
from planner.safety.geometry import PartKind
from planner.studies.relay_geometry import chain_system

PARK_PAN = np.pi  # rad added to the shoulder pan of home: the arm turned away from the object


def parked_q(robot: Robot) -> Array:
    """The parking posture of a robot left out of the beam: home, shoulder pan + pi (rad)."""
    q = np.array(robot.home, dtype=float)
    q[0] += PARK_PAN
    return q


def parked_volumes(system: System, parked: Sequence[int], grow: float) -> tuple[Volume, ...]:
    """The collision parts of the ``parked`` robots at :func:`parked_q` as fixed volumes,
    each grown by ``grow`` (m): a capsule as a cylinder and two end spheres, a box as a box
    (world frame)."""
    world = SafetyWorld(system, bare=True)
    world.update(system.stack_q([parked_q(r) for r in system.robots]))
    out: list[Volume] = []
    for part in world.parts:
        if part.robot not in parked or part.kind is PartKind.SCENE:
            continue
        tf = world.placement(part.index)
        T = make_T(np.asarray(tf.getRotation()), np.asarray(tf.getTranslation()))
        geom = world.geometry(part.index)
        name = f"parked/{part.name}"
        if hasattr(geom, "halfLength"):
            r, half = float(geom.radius) + grow, float(geom.halfLength)
            out.append(Volume(name, "cylinder", T, (r, 2 * half)))
            for end in (-half, half):
                out.append(sphere(f"{name}/end{end:+.3f}", r, T @ make_T(p=[0.0, 0.0, end])))
        else:
            out.append(box(name, (2 * np.asarray(geom.halfSide) + 2 * grow).tolist(), T))
    return tuple(out)


def rule_name(v: Violation) -> str:
    """The rule a violation breaks, with the parked robots' parts named for what they are:
    ``arm_arm (parked)`` for an arm too close to one, ``beam_arm (parked)`` for the beam."""
    parked = any(str(v.evidence.get(k, "")).startswith(("scene/parked/", "keep_out/parked/"))
                 for k in ("a", "b"))  # fmt: skip
    if parked:
        return "beam_arm (parked)" if v.check.value.startswith("beam") else "arm_arm (parked)"
    return v.check.value


@dataclass(frozen=True)
class ChainRules:
    """The rules of one sub-chain: ``safety`` on the chain's own system (its robots in beam
    order), with the object and the parked robots as fixed geometry."""

    robots: tuple[int, ...]
    safety: Safety

    def violation(self, q: Array, hits: Sequence[Array], target: Array,
                  laser: Array) -> Violation | None:  # fmt: skip
        """The worst broken rule with the chain's arms at stacked joints ``q`` (rad, the
        chain's robots in beam order) relaying the beam from ``laser`` through ``hits`` onto
        ``target``, or None."""
        P = np.vstack([laser, *hits, target])
        return self.safety.configuration(q, P) or self.safety.geometry(P)


def chain_rules(
    system: System, robots: tuple[int, ...], centre: Array, radius: float,
    clearance: float = DEFAULT_CLEARANCE,
) -> ChainRules:  # fmt: skip
    """The rules of the sub-chain ``robots`` of ``system``; the object is a sphere of
    ``radius`` about ``centre`` (m)."""
    parked = [i for i in range(system.n_robots) if i not in robots]
    chain = chain_system(system, robots)
    scene = (sphere("object", radius, make_T(p=centre)), *parked_volumes(system, parked, 0.0))
    keep_out = parked_volumes(system, parked, clearance)
    return ChainRules(robots, Safety(chain, scene, keep_out, SafetySettings(clearance=clearance)))
