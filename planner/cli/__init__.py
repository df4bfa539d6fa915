"""The ``beamrelay`` command line.

Each area keeps its commands in its own module (``planner/cli_*.py``) with only light
imports at module level, so ``beamrelay --help`` stays instant; heavy libraries (CasADi,
Pinocchio, open3d, Zenoh, matplotlib) are imported inside the commands.

Exit status (SPEC section 9): 0 success, 1 the work ran but something failed, 2 bad input
(one line on stderr, no traceback).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys

import typer

from planner.errors import InputError

app = typer.Typer(
    name="beamrelay",
    help="Relay a free-space laser beam with robot-held mirrors: plan, check, calibrate, run.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

# (module, attribute, command name) of every top-level command, and sub-apps.
_COMMANDS = [
    ("planner.cli.core", "validate", "validate"),
    ("planner.cli.core", "trace", "trace"),
    ("planner.cli.plan", "plan", "plan"),
    ("planner.cli.plan", "check", "check"),
    ("planner.cli.node", "serve", "serve"),
    ("planner.cli.node", "up", "up"),
    ("planner.cli.node", "request", "request"),
]
_GROUPS = [
    ("planner.cli.calibrate", "app", "calibrate"),
    ("planner.cli.study", "app", "study"),
    ("planner.cli.bench", "app", "bench"),
    ("drivers.cli", "app", "driver"),
]


def _exists(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def _register() -> None:
    for module, attr, name in _COMMANDS:
        if _exists(module) and hasattr(mod := importlib.import_module(module), attr):
            app.command(name)(getattr(mod, attr))
    for module, attr, name in _GROUPS:
        if _exists(module):
            app.add_typer(getattr(importlib.import_module(module), attr), name=name)


_register()


def main(argv: list[str] | None = None) -> None:
    """Console entry point: user mistakes become one line and exit status 2."""
    try:
        status = app(args=argv, standalone_mode=False)
    except InputError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        sys.exit(130)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except SystemExit:
        raise
    except Exception as exc:  # click usage errors arrive here in non-standalone mode
        import click

        if isinstance(exc, click.exceptions.ClickException):
            exc.show()
            sys.exit(2)
        if isinstance(exc, click.exceptions.Abort):
            sys.exit(130)
        raise
    # in non-standalone mode click returns the exit code of ``typer.Exit`` instead of exiting
    if isinstance(status, int) and status != 0:
        sys.exit(status)


if __name__ == "__main__":
    main()
