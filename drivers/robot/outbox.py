"""What a receiving thread hands to the control loop: a list taken all at once."""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class Outbox(Generic[T]):
    """Items a producer thread appends to :attr:`items` while holding ``lock`` (its owner's
    lock), taken by the control loop with :meth:`take`."""

    def __init__(self, lock: threading.Lock) -> None:
        self.items: list[T] = []
        self._lock = lock

    def take(self) -> list[T]:
        """The items since the last call, oldest first: an unlocked peek (a list's truth
        value is atomic), then a pointer swap under the lock, so an idle loop never waits."""
        if not self.items:
            return []
        with self._lock:
            out, self.items = self.items, []
        return out
