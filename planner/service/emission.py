"""The plan-side check of ``laser.limits``: a trajectory whose treatment exposures (intervals
less than :data:`COOL_DOWN` s apart are one, as the driver counts them) would pass a limit is
not sent (the gate's driver enforces the same limits whatever it is sent; this
check refuses up front, with the figures, what the driver would cut short). Times in s,
energies in J, power in W."""

from __future__ import annotations

from typing import Any

from schemas.scenario import LaserLimits

SLACK = 1e-9  # s
#: s dark between two intervals for them to count as two exposures (the driver's rule)
COOL_DOWN = 0.5


def exposures(spans: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """(start, on-time) of each exposure (s): intervals less than :data:`COOL_DOWN` apart
    are one."""
    out: list[tuple[float, float, float]] = []  # start, end, on-time
    for a, b in spans:
        if out and a - out[-1][1] < COOL_DOWN:
            s, _, on = out[-1]
            out[-1] = (s, b, on + b - a)
        else:
            out.append((a, b, b - a))
    return [(s, on) for s, _, on in out]


def emission_excess(laser_on: Any, power: float | None, limits: LaserLimits) -> str | None:
    """Why a trajectory's ``laser_on`` intervals (``[[t0, t1], ...]``, s) break the
    scenario's ``laser.limits`` at its ``laser.power`` (W; None: unknown, then only
    ``max_on`` is checked), or None."""
    max_on, max_spot = limits.max_on, limits.max_spot_energy
    max_session = limits.max_session_energy
    spans = [(float(a), float(b)) for a, b in laser_on]
    for a, on in exposures(spans):
        where = f"the exposure from t = {a:.3f} s"
        if max_on is not None and on > max_on + SLACK:
            return f"{where} lasts {on:.3f} s, over laser.limits.max_on {max_on:g} s"
        if max_spot is not None and power and power * on > max_spot * (1 + 1e-9):
            return (f"{where} delivers {power * on:.4g} J ({on:.3f} s at {power:g} W), over "
                    f"laser.limits.max_spot_energy {max_spot:g} J")  # fmt: skip
    total = sum(b - a for a, b in spans)
    if max_session is not None and power and power * total > max_session * (1 + 1e-9):
        return (f"the trajectory's treatment delivers {power * total:.4g} J, over "
                f"laser.limits.max_session_energy {max_session:g} J")  # fmt: skip
    return None
