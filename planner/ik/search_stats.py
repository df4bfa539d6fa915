"""What the closed-form family search saw: the counts behind a failure reason, and the
safety rejections (per reason, the one nearest to passing) that become its evidence."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.safety.model import Violation


@dataclass
class SearchStats:
    """What the search saw; the evidence of a failure."""

    members: int = 0
    grazing: int = 0
    no_ik: int = 0
    limits: int = 0
    incidence: int = 0
    min_limit_violation: float = np.inf
    min_incidence: float = np.inf
    unsafe: int = 0  # members (or configurations) rejected by the safety rules
    by_reason: dict[str, int] = field(default_factory=dict)  # rejections per reason
    nearest: dict[str, Violation] = field(default_factory=dict)  # per reason, largest margin
    evidence: dict[str, object] = field(default_factory=dict)

    def reject(self, v: Violation) -> None:
        """Count a safety rejection; per reason, keep the one nearest to passing."""
        self.unsafe += 1
        self.by_reason[v.reason] = self.by_reason.get(v.reason, 0) + 1
        if v.reason not in self.nearest or v.margin > self.nearest[v.reason].margin:
            self.nearest[v.reason] = v

    @property
    def least_unsafe(self) -> Violation | None:
        """The evidence of a target no member of which is safe: the most frequent reason's
        rejection nearest to passing."""
        if not self.by_reason:
            return None
        return self.nearest[max(self.by_reason, key=lambda r: self.by_reason[r])]
