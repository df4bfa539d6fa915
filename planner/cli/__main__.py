"""``python -m planner.cli`` runs the ``beamrelay`` command line."""

from planner.cli import main

main()
