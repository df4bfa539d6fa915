"""06: a robot model of your own: register it by name, then say ``model: <name>`` in a scenario.

Here a lab's "calibrated" UR5e is the shipped URDF with a 2 mm longer upper arm. Registered
as ``ur5e_lab`` (with the UR5e's collision shapes), any scenario can say ``model: ur5e_lab``
and gets its kinematics and its URDF's joint limits. A model needs only a factory that
returns a ``RobotModel``; see ``planner.model.robots``.

Run: python examples/06_robot_model.py
"""

import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

import planner
from planner.model.kinematics import ur5e_urdf_path
from planner.model.robots import urdf_model
from planner.model.ur5e import UR5E_SHAPES

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "paper_n1.yaml"
work = Path(tempfile.mkdtemp())

tree = ET.parse(ur5e_urdf_path())
elbow = next(j for j in tree.getroot().iter("joint") if j.get("name") == "elbow")
elbow.find("origin").set("xyz", "-0.427 0 0")  # type: ignore[union-attr]  # was -0.425
urdf = work / "ur5e_lab.urdf"
tree.write(urdf)

planner.register_model("ur5e_lab", lambda: urdf_model(urdf, "ur5e_lab", collision=UR5E_SHAPES))
scenario = work / "lab.yaml"
scenario.write_text(SCENARIO.read_text().replace("model: ur5e", "model: ur5e_lab"))

setup = planner.load(scenario)
arm = setup.system.robots[0]
print(f"robot {arm.name}: model {arm.kinematics.name}, {arm.nq} joints")
print(f"flange at zero joints: {np.round(arm.kinematics.fk(np.zeros(arm.nq))[:3, 3], 4)} m")

sol = planner.solver(setup).solve(setup.targets.points[0])
print(f"first target: status {sol.status}, spot error {1e3 * sol.error:.2e} mm")
