"""Typed errors. Each carries the evidence a user needs to act on it."""

from __future__ import annotations


class BeamrelayError(Exception):
    """Base of every error this package raises on purpose."""


class InputError(BeamrelayError):
    """A user mistake in a file, key, value or argument (CLI exit status 2).

    ``where`` names the place (``file:line key.path``), ``reason`` says what is wrong.
    """

    def __init__(self, reason: str, where: str = "") -> None:
        self.reason = reason
        self.where = where
        super().__init__(f"{where}: {reason}" if where else reason)


class ScenarioError(InputError):
    """A scenario file (or one of its includes) is invalid."""


class DatasetError(InputError):
    """A calibration dataset is invalid or insufficient."""


class PlanError(BeamrelayError):
    """Planning could not run at all (not a single failed target: those are statuses)."""


class CalibrationError(BeamrelayError):
    """Calibration ran but the data cannot determine the unknowns.

    ``directions`` names the unobservable directions found from the Jacobian.
    """

    def __init__(self, reason: str, directions: list[str] | None = None) -> None:
        self.reason = reason
        self.directions = directions or []
        super().__init__(reason)
