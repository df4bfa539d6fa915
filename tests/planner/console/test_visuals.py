"""URDF visual meshes on the console page: chosen when the URDF has them, posed like the
planner's kinematics (yourdfpy's forward kinematics against Pinocchio's)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.console.draw import RobotDrawing
from planner.console.visuals import has_visuals
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.kinematics import ur5e_urdf_path
from planner.model.transforms import make_T
from tests.drivers.conftest import free_port
from tests.paths import SCENARIOS

BOX = '<visual><origin xyz="0 0 0.02"/><geometry><box size="0.04 0.04 0.04"/></geometry></visual>'


def visual_urdf(path: Path) -> Path:
    """The shipped UR5e URDF with a box visual on every link that has an inertial."""
    text = re.sub(r"(<inertial>.*?</inertial>)", r"\1" + BOX, ur5e_urdf_path().read_text())
    path.write_text(text)
    return path


def quat_R(wxyz: Any) -> np.ndarray:
    w, x, y, z = (float(c) for c in wxyz)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])  # fmt: skip


@pytest.fixture
def server() -> Any:
    import viser

    s = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield s
    s.stop()


def test_urdf_visuals_are_detected_only_where_the_file_has_them(tmp_path: Path) -> None:
    assert has_visuals(visual_urdf(tmp_path / "vis.urdf"))
    assert not has_visuals(ur5e_urdf_path())
    (tmp_path / "broken.urdf").write_text("<robot><link name='a'>")
    assert not has_visuals(tmp_path / "broken.urdf")
    assert not has_visuals(tmp_path / "missing.urdf")


def test_a_robot_with_urdf_visuals_is_drawn_with_them_where_its_kinematics_put_it(
    tmp_path: Path, server: Any
) -> None:
    visual_urdf(tmp_path / "vis.urdf")
    text = (SCENARIOS / "paper_n1.yaml").read_text().replace("model: ur5e", "urdf: vis.urdf")
    text = text.replace("world_T_base: {xyz: [0, 0, 0]}",
                        "world_T_base: {xyz: [0.1, -0.2, 0.05], rpy_deg: [0, 0, 30]}")  # fmt: skip
    (tmp_path / "s.yaml").write_text(text)
    system = system_from_scenario(load_scenario(tmp_path / "s.yaml"))
    robot = system.robots[0]
    drawing = RobotDrawing(server, system)
    assert set(drawing.visuals) == {"arm0"}
    # the links come from the URDF; the mirror and its mount are still drawn
    assert drawing.nodes and all("arm0/" in drawing.world.parts[i].name for i, _ in drawing.nodes)
    assert not any(drawing.world.parts[i].kind.value == "link" for i, _ in drawing.nodes)

    q = np.array([0.3, -1.2, 1.4, -0.8, -1.5, 0.6])
    drawing.update({"arm0": q})
    visual = drawing.visuals["arm0"]
    frames = {h.name: h for h in visual.view._joint_frames}
    name = next(n for n in frames if n.endswith("/tool0"))
    T = make_T(quat_R(visual.root.wxyz), visual.root.position)
    parts = name[len(visual.root_name) + 1 :].split("/")
    for k in range(1, len(parts) + 1):
        h = frames.get("/".join([visual.root_name, *parts[:k]]))
        if h is not None:  # the "visual" group node sits at identity
            T = T @ make_T(quat_R(h.wxyz), h.position)
    expected = robot.world_T_base @ robot.kinematics.fk(q)
    np.testing.assert_allclose(T, expected, atol=1e-6)


def test_the_shipped_ur5e_is_drawn_with_its_collision_capsules(server: Any) -> None:
    system = system_from_scenario(load_scenario(SCENARIOS / "paper_n1.yaml"))
    drawing = RobotDrawing(server, system)
    assert drawing.visuals == {}
    assert any(drawing.world.parts[i].kind.value == "link" for i, _ in drawing.nodes)
