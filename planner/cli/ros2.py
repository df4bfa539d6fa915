"""``beamrelay ros2 bridge``: the system on ROS 2 topics over rmw_zenoh (argument parsing only)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from planner.cli.args import check_domain, stop_on_signals, wait_until_set
from planner.cli.node import EndpointOpt, PrefixOpt, ZenohConfigOpt
from planner.errors import InputError

app = typer.Typer(no_args_is_help=True, help="ROS 2 (rmw_zenoh) interoperability.")

DomainOpt = Annotated[
    int,
    typer.Option("--ros-domain", help="ROS_DOMAIN_ID the topics are published in (0-232)."),
]


@app.command("bridge")
def bridge(
    scenario: Annotated[Path, typer.Argument(help="Scenario YAML of the running system.")],
    ros_domain: DomainOpt = 0,
    rate: Annotated[
        float, typer.Option("--rate", help="Joint states and /tf publishing rate (Hz, 1-1000).")
    ] = 100.0,
    endpoint: EndpointOpt = None,
    prefix: PrefixOpt = "beamrelay",
    zenoh_config: ZenohConfigOpt = None,
) -> None:
    """Republish joint states, TF and markers as ROS 2 topics (rmw_zenoh key expressions and
    liveliness tokens) until Ctrl-C. A ROS 2 user on the same Zenoh network, with
    RMW_IMPLEMENTATION=rmw_zenoh_cpp, sees them with `ros2 topic list` and RViz."""
    check_domain(ros_domain)
    if not 1.0 <= rate <= 1000.0:
        raise InputError(f"--rate {rate}: expected 1-1000 Hz")
    if not scenario.is_file():
        raise InputError(f"scenario not found: {scenario}")
    from planner.bus.session import Keys, open_session
    from planner.io.scenario import load_scenario, scene_objects, system_from_scenario
    from planner.model.scene import SceneModel
    from planner.ros2.bridge import Ros2Bridge

    scn = load_scenario(scenario)
    system = system_from_scenario(scn)
    scene = SceneModel(scene_objects(scn))
    keys = Keys(prefix)
    session = open_session(listen=False, endpoint=endpoint, config_file=zenoh_config)
    node = Ros2Bridge(session, system, scene, keys=keys, domain=ros_domain, rate=rate)
    stop = stop_on_signals()
    node.start()
    alive = session.liveliness().declare_token(keys.alive("ros2"))
    typer.echo(f"ROS 2 bridge: domain {ros_domain}, {len(node.topics)} topics")
    try:
        wait_until_set(stop)
    finally:
        alive.undeclare()
        node.close()
        session.close()
