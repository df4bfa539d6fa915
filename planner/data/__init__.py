"""Files installed with the package: the UR5e URDF and the shipped scenarios."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def scenarios_dir() -> Path:
    """The folder of the shipped scenarios (``scenarios/`` of the repository or install)."""
    return Path(str(resources.files("scenarios")))


def shipped_scenario(name: str) -> Path:
    """Path of a shipped scenario file by name (``"paper_n1.yaml"``); FileNotFoundError if
    there is none of that name."""
    path = scenarios_dir() / name
    if not path.is_file():
        known = ", ".join(sorted(p.name for p in scenarios_dir().glob("*.yaml")))
        raise FileNotFoundError(f"no shipped scenario {name!r} (shipped: {known})")
    return path
