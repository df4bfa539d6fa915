"""The ``beamrelay`` command line.

Each area keeps its commands in its own module (``planner/cli/<area>.py``), registered here
by name, so a misspelt module or command fails at import instead of silently dropping the
command. The modules import only light libraries at module level, so ``beamrelay --help``
stays fast; heavy libraries (CasADi, Pinocchio, open3d, Zenoh, matplotlib) are imported
inside the commands.

Exit status: 0 success, 1 the work ran but something failed, 2 bad input
(one line on stderr, no traceback).
"""

from __future__ import annotations

import os
import sys
from typing import Annotated

import typer

from planner.cli import (
    bench,
    calibrate,
    collect,
    console,
    core,
    hw,
    node,
    plan,
    record,
    request,
    robot,
    ros2,
    study,
)
from planner.cli import driver as driver_cli
from planner.cli.args import command_group
from planner.errors import InputError

app = command_group(
    name="beamrelay",
    help="Relay a free-space laser beam with robot-held mirrors: plan, check, calibrate, run.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

app.command("validate")(core.validate)
app.command("trace")(core.trace)
app.command("plan")(plan.plan)
app.command("check")(plan.check)
app.command("serve")(node.serve)
app.command("up")(node.up)
app.command("request")(request.request)
app.command("console")(console.console)
app.add_typer(calibrate.app, name="calibrate")
app.add_typer(study.app, name="study")
app.add_typer(bench.app, name="bench")
app.add_typer(driver_cli.app, name="driver")
app.command("record")(record.record)
app.command("replay")(record.replay)
app.add_typer(robot.app, name="robot")
app.add_typer(hw.app, name="hw")
app.add_typer(ros2.app, name="ros2")
calibrate.app.add_typer(collect.app, name="collect")


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            text = version("beamrelay")
        except PackageNotFoundError:  # running from a source tree that is not installed
            text = "unknown (not installed)"
        typer.echo(f"beamrelay {text}")
        raise typer.Exit(0)


@app.callback()
def _root(
    show_version: Annotated[
        bool,
        typer.Option(
            "--version", is_eager=True, callback=_version, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """Relay a free-space laser beam with robot-held mirrors: plan, check, calibrate, run."""


def _click_classes(exc: BaseException) -> set[str]:
    """Names of the click exception classes ``exc`` derives from. Typer raises the exceptions
    of whichever click it uses (its own vendored copy ``typer._click`` in recent releases,
    the ``click`` package in older ones), so they are recognised by class name within those
    two packages instead of by one particular module's classes."""
    return {
        cls.__name__
        for cls in type(exc).__mro__
        if cls.__module__.split(".")[0] in ("click", "typer")
    }


def _one_line(text: str) -> str:
    return "; ".join(line.strip() for line in str(text).splitlines() if line.strip())


def _usage_error(exc: Exception) -> int:
    """Report a click usage error as one line on stderr; the exit status."""
    ctx = getattr(exc, "ctx", None)
    message = _one_line(exc.format_message())  # type: ignore[attr-defined]
    hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
    typer.echo(f"error: {message}{hint}", err=True)
    return 2


def _run(argv: list[str] | None) -> int:
    """Run the app; map every way it can end to an exit status (click's non-standalone
    mode returns ``typer.Exit``'s code and raises its usage errors)."""
    try:
        status = app(args=argv, prog_name="beamrelay", standalone_mode=False)
    except InputError as exc:
        typer.echo(f"error: {_one_line(str(exc))}", err=True)
        return 2
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        return 130
    except typer.Exit as exc:
        return int(exc.exit_code or 0)
    except BrokenPipeError:
        raise
    except Exception as exc:
        kinds = _click_classes(exc)
        if "NoArgsIsHelpError" in kinds:  # a bare group: its help on stdout
            typer.echo(exc.format_message())  # type: ignore[attr-defined]
            return 0
        if "UsageError" in kinds:
            return _usage_error(exc)
        if "ClickException" in kinds:
            typer.echo(f"error: {_one_line(exc.format_message())}", err=True)  # type: ignore[attr-defined]
            return int(getattr(exc, "exit_code", 1))
        if "Abort" in kinds:
            typer.echo("aborted", err=True)
            return 130
        raise
    return status if isinstance(status, int) else 0


def main(argv: list[str] | None = None) -> None:
    """Console entry point: user mistakes become one line on stderr and exit status 2.

    A reader that closes standard output early (``beamrelay plan ... | head``) ends the
    command quietly with status 0: standard output is pointed at the null device so the
    interpreter's final flush does not fail again (the recipe of Python's ``signal`` docs,
    which rich's Console also applies before raising ``SystemExit(1)``).
    """
    try:
        status = _run(argv)
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        status = 0
    except SystemExit as exc:
        # rich's Console applies the same recipe itself, then raises SystemExit(1)
        if not isinstance(exc.__context__, BrokenPipeError):
            raise
        status = 0
    if status:
        sys.exit(status)


if __name__ == "__main__":
    main()
