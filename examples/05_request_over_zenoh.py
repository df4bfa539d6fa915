"""05: run a planner node on a private loopback bus and send it one target over Zenoh,
exactly as a remote client (another process, another language) would.

Run: python examples/05_request_over_zenoh.py
"""

import json
import socket
from pathlib import Path

import zenoh

from planner.bus.session import Keys, open_session
from planner.service.node import PlannerNode, handler_from_scenario

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "paper_n1.yaml"

with socket.socket() as s:  # a free loopback port for this example's private bus
    s.bind(("127.0.0.1", 0))
    endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"

hub = open_session(listen=True, endpoint=endpoint)
node = PlannerNode(handler_from_scenario(SCENARIO), hub, Keys()).start()

# the client: plain zenoh, a JSON TargetRequest on beamrelay/plan
conf = zenoh.Config()
conf.insert_json5("mode", '"peer"')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
client = zenoh.open(conf)
request = {"schema": "beamrelay.request/1", "id": "example-05", "points": [[-0.49, -0.52, 0.0]]}
for reply in client.get("beamrelay/plan", payload=json.dumps(request), timeout=10.0):
    if reply.ok is not None:
        plan = json.loads(reply.ok.payload.to_bytes())
        sol = plan["solutions"][0]
        print(f"reply: {sol['status']}, error {1e3 * sol['error']:.2e} mm, q {sol['q']}")
    else:
        print("error reply:", reply.err.payload.to_bytes().decode())
client.close()
node.close()
hub.close()
