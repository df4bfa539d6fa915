"""Plans for the tests from partial plan documents (the keys a test cares about)."""

from __future__ import annotations

from typing import Any

from planner.io.plan import PLAN_SCHEMA, Plan


def as_plan(doc: dict[str, Any]) -> Plan:
    """The :class:`Plan` of a partial plan document: empty scenario, targets, solutions and
    metrics, a target's missing id and point (its index, the origin), a solution's missing
    target (its index) and a trajectory's missing tables empty, unless ``doc`` gives them."""
    full: dict[str, Any] = {"schema": PLAN_SCHEMA, "scenario": {}, "robots": [],
                            "joint_names": {}, "targets": [], "solutions": [],
                            "trajectory": None, "metrics": {"n_targets": 0, "n_ok": 0}} | doc  # fmt: skip
    full["targets"] = [{"id": k, "p": [0.0, 0.0, 0.0]} | t for k, t in enumerate(full["targets"])]
    full["solutions"] = [{"target": k} | s for k, s in enumerate(full["solutions"])]
    if full["trajectory"] is not None:
        full["trajectory"] = {"q": {}, "qd": {}, "qdd": {}} | full["trajectory"]
    return Plan.from_document(full)
