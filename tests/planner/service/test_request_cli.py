"""``beamrelay request`` reads the drivers' verdict: a rejected execution is printed with its
reason and exits 1; ``--json`` ends with one JSON object. The planner here is a stand-in
written with plain zenoh, answering a canned plan."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import pytest

from tests.drivers.conftest import free_port
from tests.planner.raw_zenoh import raw_session

PREFIX = "reqcli"
REASON = "arm0: q[0]: starts 0.2000 rad from the current state on joint elbow (tolerance 0.01 rad)"


def canned_plan(request: dict[str, Any], verdict: str | None) -> dict[str, Any]:
    """A plan answering ``request``: its first point solved, the others not; a 30 s
    trajectory (the client must not wait for it when the execution was rejected)."""
    n = len(request["points"])
    plan: dict[str, Any] = {
        "schema": "beamrelay.plan/1", "id": request["id"], "robots": ["arm0"],
        "scenario": {}, "joint_names": {"arm0": [f"j{k}" for k in range(6)]},
        "targets": [{"id": k, "p": p, "n": None} for k, p in enumerate(request["points"])],
        "solutions": [{"target": k, "status": "ok" if k == 0 else "failed",
                       "reason": None if k == 0 else "unreachable", "q": {"arm0": [0.0] * 6},
                       "error": 2e-12 if k == 0 else None, "solve_time": 0.001}
                      for k in range(n)],
        "trajectory": {"t": [0.0, 30.0], "q": {"arm0": [[0.0] * 6] * 2},
                       "qd": {"arm0": [[0.0] * 6] * 2}, "qdd": {"arm0": [[0.0] * 6] * 2}},
        "metrics": {"n_targets": n, "n_ok": 1, "duration": 30.0},
    }  # fmt: skip
    if verdict is not None:
        plan["execution"] = verdict
        plan["execution_reason"] = REASON if verdict == "rejected" else None
    return plan


class FakePlanner:
    """Token ``<prefix>/alive/planner`` and a queryable on ``<prefix>/plan``."""

    def __init__(self, endpoint: str) -> None:
        self.session = raw_session(endpoint)
        self.verdict: str | None = "accepted"
        self.requests: list[dict[str, Any]] = []
        self._token = self.session.liveliness().declare_token(f"{PREFIX}/alive/planner")
        self._q = self.session.declare_queryable(f"{PREFIX}/plan", self._on_query)

    def _on_query(self, query: Any) -> None:
        req = json.loads(query.payload.to_bytes())
        self.requests.append(req)
        verdict = self.verdict if req.get("execute") else None
        query.reply(f"{PREFIX}/plan", json.dumps(canned_plan(req, verdict)))

    def close(self) -> None:
        self._q.undeclare()
        self._token.undeclare()
        self.session.close()


@pytest.fixture
def planner() -> Iterator[tuple[FakePlanner, str]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # the fake planner hosts the bus
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    hub = zenoh.open(conf)
    fake = FakePlanner(endpoint)
    try:
        yield fake, endpoint
    finally:
        fake.close()
        hub.close()


def request(endpoint: str, *args: str) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-m", "planner.cli", "request", "--endpoint", endpoint,
            "--prefix", PREFIX, "--timeout", "20", *args]  # fmt: skip
    return subprocess.run(argv, capture_output=True, text=True, timeout=120)


def test_rejected_execution_is_printed_with_the_reason_and_exits_1(
    planner: tuple[FakePlanner, str],
) -> None:
    fake, endpoint = planner
    fake.verdict = "rejected"
    t0 = time.monotonic()
    out = request(endpoint, "--points", "0.1,0.2,0.3", "--execute")
    took = time.monotonic() - t0
    assert out.returncode == 1, out.stderr
    assert f"execution: REJECTED: {REASON}" in out.stdout.splitlines()
    assert "Traceback" not in out.stderr
    assert fake.requests[-1]["execute"] is True
    assert took < 25.0  # the 30 s trajectory that never runs is not waited for


def test_accepted_execution_is_printed_and_exits_0(planner: tuple[FakePlanner, str]) -> None:
    fake, endpoint = planner
    fake.verdict = "accepted"
    plan = canned_plan({"id": "x", "points": [[0.1, 0.2, 0.3]]}, "accepted")
    plan["trajectory"]["t"][-1] = 0.2  # a short motion to wait for
    fake._q.undeclare()

    def short(query: Any) -> None:
        req = json.loads(query.payload.to_bytes())
        query.reply(f"{PREFIX}/plan", json.dumps({**plan, "id": req["id"]}))

    fake._q = fake.session.declare_queryable(f"{PREFIX}/plan", short)
    out = request(endpoint, "--points", "0.1,0.2,0.3", "--execute")
    assert out.returncode == 0, out.stderr
    assert "execution: accepted" in out.stdout.splitlines()


def test_a_reply_without_a_verdict_counts_as_rejected(planner: tuple[FakePlanner, str]) -> None:
    fake, endpoint = planner
    fake.verdict = None  # an old planner, or a bug: the reply says nothing about execution
    out = request(endpoint, "--points", "0.1,0.2,0.3", "--execute")
    assert out.returncode == 1
    assert "execution: REJECTED: no verdict in the reply" in out.stdout.splitlines()


def test_json_ends_with_one_object_of_the_figures(planner: tuple[FakePlanner, str]) -> None:
    fake, endpoint = planner
    fake.verdict = "rejected"
    out = request(endpoint, "--points", "0.1,0.2,0.3", "--points", "1,2,3", "--execute",
                  "--json")  # fmt: skip
    assert out.returncode == 1  # rejected (and one target unsolved)
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1  # the table and the verdict went to stderr
    doc = json.loads(lines[-1])
    assert doc["id"] == fake.requests[-1]["id"]
    assert (doc["execution"], doc["execution_reason"]) == ("rejected", REASON)
    assert (doc["n_ok"], doc["n_targets"]) == (1, 2)
    assert [t["status"] for t in doc["targets"]] == ["ok", "failed"]
    assert (
        doc["targets"][0]["planned_error"] == 2e-12 and doc["targets"][1]["planned_error"] is None
    )
    assert doc["targets"][1]["reason"] == "unreachable"
    assert all(t["measured_error"] is None for t in doc["targets"])
    assert "measured_error_median" not in doc  # nothing measured
    assert f"execution: REJECTED: {REASON}" in out.stderr


def test_json_without_execute(planner: tuple[FakePlanner, str]) -> None:
    _, endpoint = planner
    out = request(endpoint, "--points", "0.1,0.2,0.3", "--json")
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["execution"] is None and doc["n_ok"] == 1 and "execution:" not in out.stderr
