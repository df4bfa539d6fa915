"""Trajectory ids on the bus: a request's trajectory sent in chunks carries
``<request id>#<k>/<n>``; the drivers, the planner's execution and its streams all read the
request back from it with :func:`base_id`."""

from __future__ import annotations

#: longest chunk suffix of a trajectory id after the "#": "<k>/<n>", numbers of 6 digits
CHUNK_SUFFIX_MAX = 13


def chunk_id(request_id: str, k: int, n: int, max_length: int = 256) -> str:
    """``<request id>#<k>/<n>`` (1-based ``k``), the request id cut to fit ``max_length``."""
    suffix = f"#{k}/{n}"
    return request_id[: max_length - len(suffix)] + suffix


def base_id(trajectory_id: str | None) -> str | None:
    """The request id of a trajectory (chunk) id: ``"r#2/5"`` -> ``"r"``; others unchanged."""
    if trajectory_id is None or "#" not in trajectory_id:
        return trajectory_id
    head, _, tail = trajectory_id.rpartition("#")
    k, _, n = tail.partition("/")
    return head if k.isdigit() and n.isdigit() and len(tail) <= CHUNK_SUFFIX_MAX else trajectory_id
