"""Timing-critical processes ask for a lower nice value; without the right they run as
they are and say so."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from planner.service.priority import priority_note

PROBE = """
import os, threading
from planner.service.priority import raise_priority
if {drop}:
    os.setresuid(65534, 65534, 65534)  # nobody: no CAP_SYS_NICE
got = raise_priority({nice})
seen = []
t = threading.Thread(target=lambda: seen.append(os.getpriority(os.PRIO_PROCESS, 0)))
t.start(); t.join()
print(got, os.getpriority(os.PRIO_PROCESS, 0), seen[0])
"""


def probe(nice: int, drop: bool = False) -> list[str]:
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(nice=nice, drop=drop)], capture_output=True,
        text=True, check=True, cwd=os.getcwd(), env={**os.environ, "PYTHONPATH": os.getcwd()},
    )  # fmt: skip
    return out.stdout.split()


@pytest.mark.skipif(os.geteuid() != 0, reason="raising priority needs root")
def test_as_root_the_process_and_its_new_threads_run_at_the_asked_nice() -> None:
    assert probe(-3) == ["-3", "-3", "-3"]


def test_a_nice_already_low_enough_is_kept() -> None:
    start = os.getpriority(os.PRIO_PROCESS, 0)
    assert probe(start + 5) == [str(start)] * 3


@pytest.mark.skipif(os.geteuid() != 0, reason="dropping to another user needs root")
def test_without_the_right_it_runs_as_it_was_and_says_so() -> None:
    got = probe(-3, drop=True)
    start = str(os.getpriority(os.PRIO_PROCESS, 0))
    assert got == ["None", start, start]
    assert "not raised" in priority_note(None) and priority_note(-3) == "priority: nice -3"
