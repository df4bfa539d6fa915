"""The thread and bus-handle lifecycle that the camera and robot nodes share.

A :class:`LoopNode` runs its ``_loop`` in one daemon thread until :meth:`LoopNode.stop`:
stop sets the ``_stop`` event, joins the thread (at most ``join_timeout`` s), lets the
subclass release its device (``_close``) and undeclares the Zenoh handles (subscribers,
tokens) in reverse order of declaration. :meth:`LoopNode.wait` blocks until the loop ends.

A loop that raises is a dead node, not a quiet one: :attr:`LoopNode.failure` keeps the
error (one line), the traceback goes to stderr, and the driver command exits non-zero
(``planner.cli.driver``), so ``beamrelay up`` sees the exit.
"""

from __future__ import annotations

import sys
import threading
import traceback
from typing import Any


class LoopNode:
    """Base of a driver node with one worker thread and a list of bus handles."""

    join_timeout = 2.0  # s: longest wait for the loop to end in stop()

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._handles: list[Any] = []  # anything with .undeclare(), in declaration order
        self.failure: str | None = None  # why the loop died (None: it did not)

    def _loop(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        """Release the backend (stop the arm, close the camera); the loop has ended."""

    def _start_loop(self, name: str) -> None:
        self._thread = threading.Thread(target=self._guarded, name=name, daemon=True)
        self._thread.start()

    def _guarded(self) -> None:
        """Run the loop; record and print an exception that ends it."""
        try:
            self._loop()
        except Exception as exc:
            if self._stop.is_set():  # shutting down: a loop that outlived stop()'s join
                return  # met the closed session (a slow raycast under load): not a death
            name = self._thread.name if self._thread is not None else "loop"
            self.failure = f"{name} loop died: {type(exc).__name__}: {exc}"
            traceback.print_exc(file=sys.stderr)

    def stop(self) -> None:
        """Stop the loop, close the backend and withdraw every bus handle (token last
        declared, first withdrawn)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.join_timeout)
        self._close()
        for h in reversed(self._handles):
            h.undeclare()
        self._handles = []

    def wait(self) -> None:
        """Block until the loop ends (Ctrl-C raises KeyboardInterrupt here)."""
        while self._thread is not None and self._thread.is_alive():
            self._thread.join(timeout=0.2)
