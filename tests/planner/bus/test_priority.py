"""Timing-critical threads ask for SCHED_FIFO, per thread; without the right they fall back
to a lower nice value (or run as they were) and say what to set."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys

import pytest

from planner.bus.priority import RT_PRIORITY, TIMING_NICE, Policy, Priority

root_only = pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO and setresuid need root")

PROBE = """
import json, os, resource, subprocess, sys, threading
from planner.bus.priority import raise_priority, raised_priority
rtprio = {rtprio}
if rtprio is not None:
    resource.setrlimit(resource.RLIMIT_RTPRIO, (rtprio, resource.getrlimit(resource.RLIMIT_RTPRIO)[1]))
if {drop}:
    os.setresuid(65534, 65534, 65534)  # nobody: no CAP_SYS_NICE
def sched():
    return [os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK, os.sched_getparam(0).sched_priority,
            os.getpriority(os.PRIO_PROCESS, 0)]
out = {{}}
def in_thread(fn):
    t = threading.Thread(target=fn); t.start(); t.join()
def rt_thread():  # like a driver's control loop: raises itself, what it starts is normal
    got = raise_priority(reset_on_fork=True)
    out["got"] = [got.policy.name, got.level, got.note]
    out["thread"] = sched()
    child = subprocess.run([sys.executable, "-c", "import os; print(os.sched_getscheduler(0))"],
                           capture_output=True, text=True)
    out["its_child"] = int(child.stdout)
in_thread(rt_thread)
out["main"] = sched()
with raised_priority() as got:  # like a Zenoh runtime started inside
    in_thread(lambda: out.setdefault("started_inside", sched()))
out["main_after"] = sched()
print(json.dumps(out))
"""


def probe(drop: bool = False, rtprio: int | None = None, env: dict[str, str] | None = None) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(drop=drop, rtprio=rtprio)], capture_output=True,
        text=True, check=True, cwd=os.getcwd(),
        env={**os.environ, "PYTHONPATH": os.getcwd(), **(env or {})},
    )  # fmt: skip
    return dict(json.loads(out.stdout))


@root_only
def test_as_root_only_the_raising_thread_and_its_threads_run_under_sched_fifo() -> None:
    nice0 = os.getpriority(os.PRIO_PROCESS, 0)
    got = probe()
    assert got["got"][:2] == ["FIFO", RT_PRIORITY] and "SCHED_FIFO 15" in got["got"][2]
    assert got["thread"][:2] == [os.SCHED_FIFO, RT_PRIORITY]
    assert got["its_child"] == os.SCHED_OTHER  # reset on fork: a parse worker stays normal
    assert got["main"] == [os.SCHED_OTHER, 0, nice0]  # the other threads are untouched
    assert got["started_inside"][:2] == [os.SCHED_FIFO, RT_PRIORITY]
    assert got["main_after"] == [os.SCHED_OTHER, 0, nice0]


@root_only
def test_without_the_right_it_falls_back_and_names_the_rtprio_limit() -> None:
    nice0 = os.getpriority(os.PRIO_PROCESS, 0)
    got = probe(drop=True, rtprio=0)
    policy, level, note = got["got"]
    assert policy == "UNCHANGED" and level == nice0  # nobody may not lower nice either
    assert "not real time" in note and "RLIMIT_RTPRIO 0" in note and "rtprio 15" in note
    assert got["thread"] == [os.SCHED_OTHER, 0, nice0]
    assert got["started_inside"] == got["main_after"] == [os.SCHED_OTHER, 0, nice0]


@root_only
@pytest.mark.skipif(
    resource.getrlimit(resource.RLIMIT_RTPRIO)[1] < 5, reason="the hard rtprio limit is below 5"
)
def test_an_rtprio_limit_below_the_asked_priority_is_used() -> None:
    got = probe(drop=True, rtprio=5)
    assert got["got"][:2] == ["FIFO", 5]
    assert got["thread"][:2] == [os.SCHED_FIFO, 5]
    assert got["main_after"][:2] == [os.SCHED_OTHER, 0]  # back from FIFO without privilege


@root_only
def test_no_rt_in_the_environment_gives_the_nice_fallback() -> None:
    got = probe(env={"BEAMRELAY_NO_RT": "1"})
    assert got["got"][:2] == ["NICE", TIMING_NICE] and "BEAMRELAY_NO_RT" in got["got"][2]
    assert got["thread"][:2] == [os.SCHED_OTHER, 0]


def test_the_note_says_what_was_obtained() -> None:
    assert Priority(Policy.FIFO, 15).note == "priority: SCHED_FIFO 15 (real time)"
    nice = Priority(Policy.NICE, -10, "SCHED_FIFO not permitted (RLIMIT_RTPRIO 0, ...)").note
    assert nice.startswith("priority: nice -10, not real time: SCHED_FIFO not permitted")
    assert "normal" in Priority(Policy.UNCHANGED, 0, "x").note
