"""``beamrelay serve / up / request``: user mistakes are one line and exit 2; no planner -> 1."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests import cli_run
from tests.drivers.conftest import free_port, wait_for


def run(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "planner.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["request", "--points", "1,2"], "expected X,Y,Z (3 numbers), got 2"),
        (["request", "--points", "1,a,3"], "expected X,Y,Z numbers"),
        (["request", "--points", "1,2,3", "--frame", "base"], "expected world or camera"),
        (
            ["request", "--points", "1,2,3", "--normals", "0,0,1", "--normals", "0,1,0"],
            "2 given for 1",
        ),
        (["request", "--points", "1,2,3", "--duration", "5"], "--duration: only with --track"),
        (["request", "--points", "1,2,3", "--track", "p", "--path"], "not with --path"),
        (["request", "--points", "1,2,3", "--track", "p", "--duration", "0"], "(0, 3600] s"),
        (["serve", "/nonexistent/scenario.yaml"], "scenario.yaml"),
        (["up", "/nonexistent/scenario.yaml", "--backend", "robotstudio"], "expected sim or ur"),
        (["up", "scenarios/paper_n1.yaml", "--ros2", "--ros-domain", "300"], "expected 0-232"),
        (
            [
                "up",
                "scenarios/paper_n1.yaml",
                "--ros2",
                "--ros-domain",
                "3",
                "--zenoh-roles",
                "scenarios/zenoh/roles",
            ],
            "the ROS 2 keys of domain 0",
        ),
        (["ros2", "bridge", "scenarios/paper_n1.yaml", "--ros-domain", "-1"], "expected 0-232"),
        (["ros2", "bridge", "scenarios/paper_n1.yaml", "--rate", "0"], "expected 1-1000 Hz"),
        (["ros2", "bridge", "/nonexistent/scenario.yaml"], "scenario not found"),
        (["record", "-o", "x.mcap", "--scenario", "scenarios/paper_n1.yaml"], "add --ros2"),
    ],
)
def test_user_mistakes_exit_2_with_one_line(args: list[str], words: str) -> None:
    cli_run.assert_usage_error(cli_run.beamrelay(*args), words)


def test_request_without_planner_fails_in_time() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = run("request", "--points", "0,0,1", "--endpoint", endpoint, "--timeout", "1")
    assert out.returncode == 2, out.stderr  # a bus problem, like a bad endpoint
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    assert f"no planner on the bus (beamrelay/alive/planner via {endpoint}) within 1 s" in lines[0]


# --- `serve` as a real process, watched by an outside client (plain zenoh) -------------------
POISONED_SERVE = """\
import sys
from planner.service.node import PlannerNode
serve = PlannerNode.serve
def poisoned(self, payload):
    if payload == b"die":  # a stand-in for a bug that kills the worker thread
        raise SystemExit("simulated fatal bug")
    return serve(self, payload)
PlannerNode.serve = poisoned
from planner.cli import main
main(sys.argv[1:])
"""


class Served:
    """``beamrelay serve`` on a private port (optionally through a patched entry point)."""

    def __init__(self, tmp: Path, prefix: str, code: str | None = None) -> None:
        from tests.planner.raw_zenoh import raw_session, token_exists
        from tests.test_e2e import SCENARIO

        scenario = tmp / "scenario.yaml"
        scenario.write_text(SCENARIO)
        self.prefix = prefix
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        entry = ["-c", code] if code is not None else ["-m", "planner.cli"]
        argv = [sys.executable, *entry, "serve", str(scenario), "--endpoint", self.endpoint,
                "--prefix", prefix]  # fmt: skip
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.client = raw_session(self.endpoint)
        self.token = f"{prefix}/alive/planner"
        wait_for(lambda: token_exists(self.client, self.token), 120.0, "planner token")

    def rss_mb(self) -> tuple[float, float]:
        """(resident, peak resident) memory of the process in MB (Linux /proc)."""
        status = Path(f"/proc/{self.proc.pid}/status").read_text().splitlines()
        kb = {k: float(v.split()[0]) for k, v in (line.split(":", 1) for line in status)
              if k in ("VmRSS", "VmHWM")}  # fmt: skip
        return kb["VmRSS"] / 1024, kb["VmHWM"] / 1024

    def good(self) -> dict:
        import json

        from tests.planner.raw_zenoh import ask

        body = {"schema": "beamrelay.request/1", "id": "g", "points": [[-0.54, -0.57, -0.06]]}
        ok, reply = ask(self.client, f"{self.prefix}/plan", json.dumps(body).encode(), 60.0)
        plan = json.loads(reply)
        assert ok, plan
        return dict(plan)

    def close(self) -> tuple[str, str]:
        self.client.close()
        if self.proc.poll() is None:
            self.proc.terminate()
        out, err = self.proc.communicate(timeout=30)
        return out.decode(errors="replace"), err.decode(errors="replace")


def test_serve_refuses_a_flood_of_20_mb_queries_without_growing(tmp_path: Path) -> None:
    import json

    served = Served(tmp_path, "flood")
    try:
        assert served.good()["solutions"][0]["status"] == "ok"
        before, _ = served.rss_mb()
        body = b'{"schema":"beamrelay.request/1","id":"big","points":[[0,0,0]]' + b" " * 20_000_000
        body += b"}"
        pending = [served.client.get("flood/plan", payload=body, timeout=120)
                   for _ in range(60)]  # fmt: skip
        errors = []
        for replies in pending:
            reply = next(iter(replies))
            assert reply.ok is None
            errors.append(json.loads(reply.err.payload.to_bytes()))
        time.sleep(1.0)
        after, peak = served.rss_mb()
        assert served.good()["solutions"][0]["status"] == "ok"
        print(f"planner memory: {before:.0f} MB before sixty 20 MB queries, {after:.0f} MB after "
              f"(peak {peak:.0f} MB)")  # fmt: skip
    finally:
        served.close()
    assert all(e["field"] == "body" and f"body of {len(body)} bytes exceeds" in e["error"]
               for e in errors), errors[0]  # fmt: skip
    assert after - before < 300.0  # 1.2 GB were sent; unguarded, the planner grew by 1.2 GB


def test_serve_exits_nonzero_when_its_worker_dies(tmp_path: Path) -> None:
    from tests.planner.raw_zenoh import token_exists

    served = Served(tmp_path, "dies", POISONED_SERVE)
    served.good()
    served.client.put("dies/targets", b"die")
    try:
        served.proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        served.close()
        raise AssertionError("serve kept running with a dead worker") from None
    assert not token_exists(served.client, served.token)
    out, err = served.close()
    assert served.proc.returncode == 1, (out, err)
    assert "error: planner node failed: the planner worker thread stopped; exiting" in err
    assert "planner stopped after 1 requests" in out


@pytest.mark.parametrize("command", ["serve", "up"])
def test_online_calibration_never_overwrites_a_users_file(command: str) -> None:
    from tests.paths import REPO

    scenario, other = REPO / "scenarios" / "paper_n1.yaml", REPO / "scenarios" / "n2_relay.yaml"
    before = other.read_bytes()
    out = cli_run.beamrelay(command, scenario, "--online-calibration", other)
    cli_run.assert_usage_error(out, "refusing to overwrite")
    assert other.read_bytes() == before
