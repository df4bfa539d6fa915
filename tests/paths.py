"""Where the repository's files are, for tests at any depth of the tests tree."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SCENARIOS = REPO / "scenarios"
