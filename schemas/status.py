"""The outcome vocabulary of plan.json and its replies, as string enums: a target's
:class:`Status` and failure :class:`Reason`, a closed-loop target's :class:`ServoStatus`
and what cut its run short (:class:`Interruption`).

String enums, so a document carries exactly the strings the file format names:
``Status.OK == "ok"`` and ``json.dumps(Reason.OCCLUDED) == '"occluded"'``. They live with
the schemas so that every layer compares with them (the bus's event log included), and
:mod:`planner.model.status` re-exports them.
"""

from __future__ import annotations

from enum import StrEnum


class Status(StrEnum):
    """Outcome of one target."""

    OK = "ok"
    FAILED = "failed"


class Reason(StrEnum):
    """Why a target failed (machine-readable, as written to plan.json)."""

    UNREACHABLE = "unreachable"  # no configuration sends the beam there (reach, incidence)
    OUTSIDE_ROI = "outside_roi"  # only with a mirror hit outside its region of interest
    JOINT_LIMITS = "joint_limits"  # only outside the joint position limits
    BACK_FACE = "back_face"  # only with the beam on a mirror's back face or the target behind
    OCCLUDED = "occluded"  # the beam crosses a scene object or a robot link
    KEEP_OUT = "keep_out"  # the beam (or the target) inside a keep-out volume
    COLLISION = "collision"  # arms, or an arm and the scene, closer than the clearance
    SOLVER_FAILED = "solver_failed"  # the solver gave no usable answer


class ServoStatus(StrEnum):
    """How a target's servo run ended (:mod:`planner.servo.loop` ends one with the first
    six), and, in a closed-loop report, the three of a target with no run of its own."""

    CONVERGED = "converged"
    NOT_IMPROVING = "not_improving"
    NOT_SEEN = "not_seen"
    REFUSED = "refused"
    MAX_ITERATIONS = "max_iterations"
    ABORTED = "aborted"  # a stop: nothing more was sent
    NOT_PLANNED = "not_planned"  # the target was not solved: never servoed
    REJECTED = "rejected"  # the drivers refused one of its moves: the run ended there
    NOT_EXECUTED = "not_executed"  # after an earlier target's refusal


class Interruption(StrEnum):
    """What cut a closed-loop target's run short (its row's ``reason``; a refused servo step
    gives a :class:`Reason` instead)."""

    STOP = "stop"  # a stop on the bus made the drivers brake
    EXECUTION = "execution"  # a robot driver refused a move
