"""``beamrelay console``: the operator page in a browser (argument parsing only)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from planner.cli.args import stop_on_signals, wait_until_set
from planner.cli.node import EndpointOpt, PrefixOpt, ZenohConfigOpt
from planner.errors import InputError

WorkdirOpt = Annotated[
    Path | None,
    typer.Option(
        "--workdir",
        help="Working directory of the calibration wizard's files (created if missing; "
        "default: $XDG_DATA_HOME/beamrelay/console, i.e. ~/.local/share/beamrelay/console).",
    ),
]


def console(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML of the running system.")],
    port: Annotated[int, typer.Option("--port", help="Web server port.")] = 8080,
    host: Annotated[
        str,
        typer.Option(
            "--host",
            help="Address to listen on (default loopback only; the page opens only with "
            "the token in the URL this command prints).",
        ),
    ] = "127.0.0.1",
    max_points: Annotated[
        int, typer.Option("--max-points", help="Cloud points sent to the browser per frame.")
    ] = 30_000,
    workdir: WorkdirOpt = None,
    endpoint: EndpointOpt = None,
    prefix: PrefixOpt = "beamrelay",
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Serve the operator console until Ctrl-C: live cloud, robots and beam; click targets
    on the cloud, preview, execute, stop."""
    import os

    from planner.console.address import check_free, check_host, check_port, is_loopback
    from planner.console.app import Console
    from planner.console.workdir import ensure_dir
    from planner.service.token import TOKEN_ENV, check_token

    check_port(port)
    host = check_host(host)
    if not scenario.is_file():
        raise InputError(f"scenario not found: {scenario}")
    if not 100 <= max_points <= 2_000_000:
        raise InputError(f"--max-points {max_points}: expected 100-2000000")
    token = os.environ.get(TOKEN_ENV) or None
    if token is not None:
        try:
            check_token(token)
        except ValueError as exc:
            raise InputError(str(exc)) from None
    if not is_loopback(host):
        typer.echo(f"warning: the console listens on {host}, beyond this machine, over plain "
                   "HTTP: anyone who sees its URL (token included) can move the robots",
                   err=True)  # fmt: skip
    folder = ensure_dir(workdir, "--workdir") if workdir is not None else None
    check_free(host, port)
    from planner.bus import events

    events.configure("console")
    app = Console(scenario, host=host, port=port, endpoint=endpoint, prefix=prefix,
                  zenoh_config=zenoh_config, max_points=max_points, token=token, workdir=folder).start()  # fmt: skip
    stop = stop_on_signals()
    typer.echo(f"console of {app.name} on {app.url}")
    try:
        wait_until_set(stop)
    finally:
        app.close()
