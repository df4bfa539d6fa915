"""The operator console in a real (headless) browser on the simulated system.

``beamrelay up scenarios/paper_n1.yaml --console`` runs on a private bus; headless chromium
opens the page. The first test waits for the cloud to be drawn, clicks a known point of the
board (its pixel computed from the page's starting camera), checks the target listed with
the board's coordinates, plans, executes, and checks on the bus that the arm moved and that
the spot the camera measured lies at the clicked point. The second marks a path: the
operator picks "polyline" in the dropdown, clicks three points of the board, previews,
executes, and the spots the camera saw (on the test's own bus client) must sweep the clicked
polyline from one end to the other, in order; then the path runs again (sent from the test's
bus client) and the operator presses STOP while the arm moves, then once more and closes the
browser: the console must publish STOP
(within 1.5 s of the close) and the arm come to rest. Between the two, the calibration
wizard runs hand-eye on 3 poses to a calibration file in the working directory given to
``up`` (``--console-workdir``), compared with the simulator's true camera pose. The page opens only with the token ``up`` printed in its URL. Figures (page load to first cloud, cloud frames per second
received by the browser, its render rate, click-to-preview latency for a target and for the
path) are printed (page load to first cloud also on the page's own clock: when the cloud message
arrived and the frame drawing it ended, apart from the webdriver's screenshot latency), and every
Execute press a late planner heartbeat stopped.
"""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.console.view import default_view
from planner.io.scenario import (
    load_scenario,
    scene_objects,
    system_from_scenario,
)
from planner.service.client import PlanClient, RequestError, make_request
from tests.drivers.conftest import free_port, wait_for
from tests.paths import SCENARIOS
from tests.planner.console.browser import (
    calm,
    canvas_rect,
    chromium_paths,
    click_button,
    click_element,
    click_world_point,
    find_button,
    first_frame_after,
    open_browser,
    open_folder,
    page_text,
    project,
    render_fps,
    screenshot,
    select_option,
    set_number,
    wait_text,
)
from tests.planner.raw_zenoh import Inbox

pytestmark = [pytest.mark.slow, pytest.mark.serial, pytest.mark.timeout(600)]

SCENARIO = SCENARIOS / "paper_n1.yaml"
BOARD_TOP = -0.06  # m, world z of the board's top face
BOARD_CENTRE = np.array([-0.492, -0.55, BOARD_TOP])
BOARD_HALF = 0.15
CLICK = np.array([-0.50, -0.57, BOARD_TOP])  # the point of the board the operator clicks
TARGET_ROW = re.compile(r"#0\s+(-?\d+\.\d), (-?\d+\.\d), (-?\d+\.\d) mm")
REQUEST_ID = re.compile(r"\(request ([0-9a-f]{12})\)")
MEASURED_ROW = re.compile(r"measured \((-?\d+\.\d), (-?\d+\.\d), (-?\d+\.\d)\) mm")
#: the page's address ``up`` prints, with the launch's token
PAGE_URL = re.compile(r"operator console: (http://127\.0\.0\.1:\d+/\?token=[\w-]+)")
#: bytes above which a websocket message is a cloud frame (a 30 k-point frame is ~0.3 MB)
CLOUD_MESSAGE_BYTES = 60_000
#: the console's working directory (``up --console-workdir``), under the module's tmp folder
WORKDIR = "console-workdir"


def saturated(img: np.ndarray) -> np.ndarray:
    """Pixels with a strongly coloured RGB (the cloud's depth ramp; the background, grid and
    translucent board are greys)."""
    c = img.astype(int)
    return (c.max(axis=2) - c.min(axis=2)) > 90


def board_box(view: object, rect: tuple[float, float, float, float]) -> tuple[slice, slice]:
    """Rows and columns of the screenshot inside the projected board (inner 60 %)."""
    corners = BOARD_CENTRE + 0.6 * BOARD_HALF * np.array(
        [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float
    )
    uv = project(view.position, view.look_at, view.up, view.fov, corners, rect[2], rect[3])  # type: ignore[attr-defined]
    u0, v0 = np.floor(uv.min(axis=0)).astype(int)
    u1, v1 = np.ceil(uv.max(axis=0)).astype(int)
    top, left = int(rect[1]), int(rect[0])
    return slice(top + v0, top + v1), slice(left + u0, left + u1)


def wait_http(url: str, timeout: float) -> None:
    def up() -> bool:
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                return bool(r.status == 200)
        except OSError:
            return False

    wait_for(up, timeout, f"the console page at {url}")


def execute(d: object, done: re.Pattern[str] = MEASURED_ROW, attempts: int = 5
            ) -> tuple[str, float]:  # fmt: skip
    """Press Execute until the motion runs through: a driver refuses, or brakes to a stop,
    when the planner's heartbeat is late, which a starved shared machine causes; the page
    then says so and the operator presses again (each refused press is printed). Returns
    the page text once it shows ``done`` (the measured result) and when (monotonic s) the
    last press was made; fails when every press was refused: the page and the system are
    what this test checks, and a safety path that refuses every motion is a failure."""
    seen: set[str] = set(REQUEST_ID.findall(page_text(d)))
    faults: list[str] = []
    for _ in range(attempts):
        arm(d)
        seen |= set(REQUEST_ID.findall(page_text(d)))
        pressed = time.monotonic()
        click_button(d, "Execute")
        old = frozenset(seen)
        text = wait_text(d, lambda t, old=old: (set(REQUEST_ID.findall(t)) - old
                         and "execution:" in t) or "press Arm" in t, 180.0,
                         "the reply to Execute")  # fmt: skip
        seen |= set(REQUEST_ID.findall(text))
        if "press Arm" in text:  # the arming dropped before the press (a fault or late beat)
            faults.append(re.search(r"not armed[^\n]*", text).group(0))  # type: ignore[union-attr]
            print(f"\nExecute press {len(faults)} refused: {faults[-1]}")
            continue
        if "execution: accepted" in text:
            text = wait_text(d, lambda t: done.search(t) or "driver: " in t, 60.0,
                             "the measured result")  # fmt: skip
            if "driver: " not in text:
                return text, pressed
        # any other refusal or fault is a failure (the health panel always says "heartbeat")
        fault = re.search(r"driver: [^\n]*heartbeat[^\n]*|no heartbeat from planner[^\n]*", text)
        assert fault, text
        faults.append(fault.group(0))
        print(f"\nExecute press {len(faults)} stopped for a late heartbeat: {fault.group(0)}")
    raise AssertionError(f"all {attempts} Execute presses stopped for a late planner heartbeat: "
                         f"{faults}")  # fmt: skip


def arm(d: Any, attempts: int = 5) -> str:
    """Press Arm until the page is armed (it previews, then says what Execute will do); a
    planner heartbeat the console has not heard for 1 s refuses it (printed, pressed again).
    Returns the page text once armed."""
    for k in range(attempts):
        old = frozenset(REQUEST_ID.findall(page_text(d)))
        click_button(d, "Arm")
        text = wait_text(d, lambda t, old=old: (set(REQUEST_ID.findall(t)) - old
                         and ("ARMED for" in t or "not armed: " in t))
                         or "still running" in t, 180.0, "the page armed")  # fmt: skip
        if "ARMED for" in text:
            assert re.search(r"Execute runs \d+/\d+ targets, motion \d+\.\d s, treatment laser "
                             r"on \d+\.\d\d s", text), text  # fmt: skip
            return text
        refused = re.search(r"not armed: [^\n]*|a request is still running[^\n]*", text)
        print(f"\nArm press {k + 1} refused: {refused.group(0) if refused else text}")
        time.sleep(1.0)
    raise AssertionError(f"all {attempts} Arm presses were refused")


def gated(text: str) -> str:
    """A scenario's text with its laser behind a gate on arm0's digital output 0 (5 mW):
    the page shows the treatment laser's state, and a STOP must switch it off."""
    at = text.index("    world_T_laser:")
    end = text.index("\n", at) + 1
    return text[:end] + "    power: 0.005\n    gate: {robot: arm0, output: 0}\n" + text[end:]


@pytest.fixture(scope="module")
def system_up(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    tmp_path = tmp_path_factory.mktemp("console")
    if chromium_paths() is None:
        pytest.skip("chromium and chromedriver are not installed (`make sysdeps` installs them)")
    endpoint, port = f"tcp/127.0.0.1:{free_port()}", free_port()
    scenario = tmp_path / "paper_n1_gated.yaml"  # the treatment laser behind arm0's gate
    scenario.write_text(gated(SCENARIO.read_text()))
    argv = [sys.executable, "-m", "planner.cli", "up", str(scenario), "--console",
            "--console-port", str(port), "--endpoint", endpoint, "--no-live",
            "--log-dir", str(tmp_path / "logs"), "--console-workdir",
            str(tmp_path / WORKDIR)]  # fmt: skip
    log = (tmp_path / "up.log").open("wb")
    proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    client = None
    try:
        client = PlanClient(endpoint=endpoint)
        client.watch()
        wait_for(lambda: "arm0" in client.recorder.joints, 120.0, "arm0 joint states")
        up_log = tmp_path / "up.log"
        wait_for(lambda: PAGE_URL.search(up_log.read_text()), 60.0, "the console's URL")
        url = PAGE_URL.search(up_log.read_text()).group(1)  # type: ignore[union-attr]
        assert url.startswith(f"http://127.0.0.1:{port}/?token=")
        wait_http(url, 120.0)
        yield url, client, tmp_path
    finally:
        if client is not None:
            client.close()
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class Page:
    """One browser on the console page for the module's tests (opening one and drawing the
    first cloud costs 15-25 s on a starved machine). ``get()`` opens it when there is none
    (first use, or after a test closed the tab) and waits for the cloud on the board."""

    def __init__(self, url: str, view: Any) -> None:
        self.url, self.view = url, view
        self.d: Any = None
        self.first_cloud: float | None = None  # s from page load to the cloud, when opened
        #: s from navigation start to the first cloud message and its frame, on the page's clock
        self.first_cloud_page: tuple[float, float] | None = None

    def get(self) -> Any:
        if self.d is not None:
            return self.d
        d = open_browser()
        t0 = time.monotonic()
        d.get(self.url)
        calm(d)
        rows, cols = board_box(self.view, canvas_rect(d))
        wait_for(lambda: float(saturated(screenshot(d)[rows, cols]).mean()) > 0.3, 180.0,
                 "the cloud drawn on the board")  # fmt: skip
        self.first_cloud = time.monotonic() - t0
        self.first_cloud_page = first_frame_after(d, CLOUD_MESSAGE_BYTES)
        self.d = d
        return d

    def close(self) -> None:
        d, self.d = self.d, None
        if d is not None:
            with contextlib.suppress(Exception):
                d.quit()


@pytest.fixture(scope="module")
def page(system_up) -> Iterator[Page]:  # type: ignore[no-untyped-def]
    scn = load_scenario(SCENARIO)
    p = Page(system_up[0], default_view(system_from_scenario(scn), scene_objects(scn)))
    yield p
    p.close()


def test_operator_clicks_the_board_plans_and_executes(system_up, page: Page) -> None:  # type: ignore[no-untyped-def]
    _, client, tmp = system_up
    view = page.view
    d = page.get()
    first_cloud, on_page = page.first_cloud, page.first_cloud_page
    try:
        rect = canvas_rect(d)
        rows, cols = board_box(view, rect)
        img = screenshot(d)
        (tmp / "console.png").write_bytes(d.get_screenshot_as_png())
        assert img.std() > 20, "blank page"
        assert float(saturated(img[rows, cols]).mean()) > 0.3  # the cloud covers the board
        assert float(saturated(img).mean()) < 0.5  # and not the whole page

        n0 = d.execute_script("return window.__ws.length;")
        fps = render_fps(d, 5.0)
        msgs = d.execute_script("return window.__ws.slice(arguments[0]);", n0)
        clouds = [t for t, n in msgs if n > CLOUD_MESSAGE_BYTES]
        cloud_rate = (
            (len(clouds) - 1) / ((clouds[-1] - clouds[0]) / 1e3) if len(clouds) > 1 else 0.0
        )

        click_world_point(d, view, rect, CLICK)
        text = wait_text(d, lambda t: TARGET_ROW.search(t), 120.0, "the clicked target listed")
        picked = 1e-3 * np.array([float(x) for x in TARGET_ROW.search(text).groups()])  # type: ignore[union-attr]
        # the click ray meets the board at CLICK; a pixel is ~1.5 mm there, the cloud's
        # points lie on a ~2-4 mm grid with 1.3 mm depth noise
        assert np.linalg.norm(picked[:2] - CLICK[:2]) < 0.008, picked
        assert abs(picked[2] - BOARD_TOP) < 0.005, picked

        wait_text(d, lambda t: "1/1 targets solved" in t, 120.0, "the preview of the click")
        latency = re.search(r"click_to_preview (\d+) ms", page_text(d))
        click_button(d, "Plan (preview)")
        wait_text(d, lambda t: "1/1 targets solved" in t and "reply in" in t, 120.0, "the preview")

        q_before = client.recorder.joints["arm0"][1].copy()
        text, _ = execute(d)
        measured = 1e-3 * np.array([float(x) for x in MEASURED_ROW.search(text).groups()])  # type: ignore[union-attr]
        q_after = client.recorder.joints["arm0"][1]
        assert float(np.max(np.abs(q_after - q_before))) > 1e-3, "the arm did not move"
        # the beam landed where the operator clicked: the picked point (within the cloud's
        # noise of the board) and the measured spot agree
        assert np.linalg.norm(measured - picked) < 0.004, (measured, picked)
        assert np.linalg.norm(measured[:2] - CLICK[:2]) < 0.01, measured
        (tmp / "console_executed.png").write_bytes(d.get_screenshot_as_png())
        with contextlib.suppress(OSError):
            Path("/tmp/beamrelay-console.png").write_bytes(d.get_screenshot_as_png())
        print(
            f"\nconsole figures: page load to first cloud "
            f"{'(page reused)' if first_cloud is None else f'{first_cloud:.2f} s'} (screenshots; "
            f"on the page's clock: cloud message at "
            f"{'?' if on_page is None else f'{on_page[0]:.2f} s, drawn by {on_page[1]:.2f} s'}); "
            f"cloud frames "
            f"received {cloud_rate:.1f}/s; render {fps:.1f} fps; click to preview "
            f"{latency.group(1) if latency else '?'} ms"
        )
    except BaseException:
        page.close()  # a failed test leaves no half-used page to the next
        raise


#: the polyline the operator clicks on the board (150 mm: 152 samples at 1 mm)
PATH_CLICKS = BOARD_CENTRE + np.array([[-0.05, -0.03, 0.0], [0.02, -0.03, 0.0], [0.03, 0.05, 0.0]])
ROW = r"#{k}\s+(-?\d+\.\d), (-?\d+\.\d), (-?\d+\.\d) mm"
SOLVED = re.compile(r"(\d+)/(\d+) targets solved")
MARKED = re.compile(
    r"marked path: (\d+) spots with the laser on, covering (\d+\.\d) of (\d+\.\d) mm; distance "
    r"to the planned path median (\d+\.\d+) mm, max (\d+\.\d+) mm"
)
#: m: a spot this close to the clicked polyline is on it (cloud noise of the picks ~1-2 mm)
ON_PATH = 0.004


def test_operator_runs_the_hand_eye_wizard_to_a_calibration_file(system_up, page: Page) -> None:  # type: ignore[no-untyped-def]
    """The wizard on the simulated cell: hand-eye, 3 poses (the least) at 1 rad/s (the
    fastest), collect, calibrate; the file lands in the working directory ``up`` was given,
    and its camera pose is the simulator's true one within the deviation the calibration
    itself reports."""
    from ruamel.yaml import YAML
    from scipy.spatial.transform import Rotation

    _, client, tmp = system_up
    workdir = tmp / WORKDIR
    d = page.get()
    t0 = time.monotonic()
    q_start = joints(client)[0]
    open_folder(d, "Calibration wizard", "poses")
    select_option(d, "calibration", "handeye")
    set_number(d, "poses", 3)
    set_number(d, "speed [rad/s]", 1.0)  # as tests/drivers/test_collect.py: the fastest
    click_button(d, "1. Collect data (moves the robot)")
    pressed = time.monotonic()
    text = wait_text(d, lambda t: '"collected": ' in t, 240.0,
                     "the collection's summary")  # fmt: skip
    collected = time.monotonic() - pressed
    log = wizard_log(text)  # the page's text is long: a failure shows the wizard's own lines
    assert '"planned": 3' in text and '"collected": 3' in text, log
    # the arm is back where the wizard found it: the next test plans from there
    assert "returned to the start pose" in text or "at its start pose" in text, log
    assert float(np.max(np.abs(joints(client)[0] - q_start))) < 3e-3
    click_button(d, "2. Calibrate and write the file")
    wait_text(d, lambda t: "kind: handeye" in t, 120.0, "the report")
    out = workdir / "handeye.yaml"
    assert (workdir / "handeye_data.json").is_file() and out.is_file()
    doc = YAML(typ="safe").load(out.read_text())
    assert doc["report"]["kind"] == "handeye" and doc["report"]["solver"]["converged"]
    pose = doc["system"]["camera"]["world_T_camera"]
    truth = system_from_scenario(load_scenario(SCENARIO), truth=True).camera
    assert truth is not None
    err_t = float(np.linalg.norm(np.array(pose["xyz"]) - truth.world_T_camera[:3, 3]))
    R = Rotation.from_quat(pose["quat"]).as_matrix()  # [x, y, z, w]
    err_r = float(Rotation.from_matrix(truth.world_T_camera[:3, :3].T @ R).magnitude())
    sd = doc["report"]["std"]["world_T_camera"]
    sd_t, sd_r = (
        float(np.linalg.norm(sd["translation_m"])),
        float(np.linalg.norm(sd["rotation_rad"])),
    )
    print(f"\nwizard: collection of 3 poses {collected:.1f} s, whole test {time.monotonic() - t0:.1f} s;"
          f" camera {1e3 * err_t:.2f} mm (1 sigma {1e3 * sd_t:.2f} mm), {np.rad2deg(err_r):.3f} deg"
          f" (1 sigma {np.rad2deg(sd_r):.3f} deg) from its true pose")  # fmt: skip
    # as tests/drivers/test_collect.py: within the D435 noise the calibration predicts
    assert err_t < 5 * sd_t + 5e-4 and err_r < 5 * sd_r + 1e-4
    assert sd_t < 0.02


def wizard_log(text: str) -> str:
    """The collection's own lines in the page's text (poses, skips, the return, the summary)."""
    keep = ("pose", "collected", "returned", "start pose", "interrupted", "error")
    return "\n".join(line for line in text.splitlines() if any(k in line for k in keep))


def picked_rows(text: str, n: int) -> np.ndarray:
    """The first ``n`` targets of the page's list (world, m)."""
    rows = [re.search(ROW.format(k=k), text) for k in range(n)]
    assert all(rows), text
    return 1e-3 * np.array([[float(x) for x in r.groups()] for r in rows])  # type: ignore[union-attr]


def test_operator_marks_a_clicked_polyline_on_the_board(system_up, page: Page) -> None:  # type: ignore[no-untyped-def]
    from planner.console.sweep import polyline_distance

    _, client, tmp = system_up
    scn = load_scenario(SCENARIO)
    view = page.view
    d: Any = page.get()
    try:
        rect = canvas_rect(d)
        click_button(d, "Clear all")
        wait_text(d, lambda t: "no targets" in t, 30.0, "an empty target list")
        select_option(d, "visit as", "polyline")
        for k, p in enumerate(PATH_CLICKS):
            click_world_point(d, view, rect, p)
            wait_text(d, lambda t, k=k: re.search(ROW.format(k=k), t), 120.0, f"target #{k}")
        picked = picked_rows(page_text(d), 3)
        assert np.max(np.linalg.norm(picked[:, :2] - PATH_CLICKS[:, :2], axis=1)) < 0.008, picked
        length = float(np.sum(np.linalg.norm(np.diff(picked, axis=0), axis=1)))

        # the last click previews the whole path: every resampled sample solved
        def path_previewed(t: str) -> bool:
            m = SOLVED.search(t)
            return bool(m) and int(m.group(2)) > 100 and "click_to_preview" in t

        text = wait_text(d, path_previewed, 180.0, "the preview of the clicked path")
        n_ok, n = map(int, SOLVED.search(text).groups())  # type: ignore[union-attr]
        assert n_ok == n and abs(n - (round(1e3 * length) + 1)) <= 3, (n_ok, n, length)
        latency = re.search(r"click_to_preview (\d+) ms", text)

        text, since = execute(d, MARKED)
        n_marked, covered, total, median, worst = MARKED.search(text).groups()  # type: ignore[union-attr]
        assert int(n_marked) > 10 and float(total) == pytest.approx(1e3 * length, abs=1.0), (
            f"planned path {total} mm, clicked {1e3 * length:.2f} mm, previewed {n} samples;"
            f" picks {np.round(1e3 * picked, 1).tolist()} mm; page: {text[-1500:]}"
        )
        assert float(covered) > 0.9 * float(total), text
        assert float(worst) < 2.0, text  # mm: the beam marked the planned path

        # independently, on the test's own bus client: the spots the camera saw near the
        # clicked polyline cover it, in order
        with client.recorder.lock:
            seen = [(sp.t, sp.p_camera) for sp in client.recorder.spots if sp.arrived >= since]
        world_T_camera = system_from_scenario(scn).world_T_camera(None)
        times = np.array([t for t, _ in seen])  # capture stamps (s)
        P = np.array([p for _, p in seen]) @ world_T_camera[:3, :3].T + world_T_camera[:3, 3]
        dist, s = polyline_distance(picked, P)
        on = dist < ON_PATH
        assert s[on].max() - s[on].min() > 0.9 * length, (s[on].min(), s[on].max(), length)
        # the sweep (the planner may run the path either way): from the last visit of the
        # end the arm did not stop at, to the first arrival at the end it stopped at (the
        # approach before it may cross the path)
        idx = np.flatnonzero(on)
        stop_end = s[idx[-1]] > 0.5 * length
        near_stop = on & ((s > length - 0.002) if stop_end else (s < 0.002))
        near_other = on & ((s < 0.002) if stop_end else (s > length - 0.002))
        assert near_other.any() and near_stop.any(), "the spot did not visit both ends"
        i_start = int(np.flatnonzero(near_other)[-1])
        i_end = int(np.flatnonzero(near_stop & (np.arange(len(s)) > i_start))[0])
        sweep = on & (np.arange(len(s)) >= i_start) & (np.arange(len(s)) <= i_end)
        # in order: along the sweep the spot advances steadily from one end to the other
        # (its speed is not checked: the simulated camera's frame times drift by up to a
        # second on a loaded 2-core machine, which made 20 mm/s read as 30-35 mm/s)
        along = s[sweep][np.argsort(times[sweep], kind="stable")]  # arc length, in time order
        rho = np.corrcoef(np.argsort(np.argsort(along)), np.arange(along.size))[0, 1]
        assert abs(rho) > 0.95 and np.ptp(s[sweep]) > 0.9 * length, (rho, np.ptp(s[sweep]))
        (tmp / "console_path.png").write_bytes(d.get_screenshot_as_png())
        print(f"\nconsole figures (path of {n} samples): click to preview "
              f"{latency.group(1) if latency else '?'} ms; marked {n_marked} spots, covering "
              f"{covered} of {total} mm, distance median {median} mm, max {worst} mm")  # fmt: skip
        # the big STOP pressed mid-execution with the panel scrolled to its end, then the tab
        # closed mid-execution: both stop the arm
        pressed, rest = stopped_by(d, client, "button", picked)
        print(f"\nbig STOP pressed mid-execution (panel scrolled): on the bus {pressed:.2f} s later, the arm at rest "
              f"{rest:.2f} s after the press")  # fmt: skip
        wait_text(d, lambda t: "STOP sent" in t, 60.0, "the page saying STOP was sent")
        # the space bar, with the focus on Execute (a browser presses a focused button on
        # the space bar): STOP, and nothing else pressed
        pressed, rest = stopped_by(d, client, "space", picked)
        print(f"\nspace bar mid-execution (Execute focused): STOP on the bus {pressed:.2f} s "
              f"later, the arm at rest {rest:.2f} s after the press")  # fmt: skip
        text = page_text(d)  # Execute, pressed unarmed, would say "not armed ...: press Arm"
        assert "STOP sent" in text and "press Arm" not in text, text
        page.d = None  # the tab is closed next
        closed, rest = stopped_by(d, client, "close", picked)
        d = None
        print(f"\ntab closed mid-execution: STOP on the bus {closed:.2f} s later, the arm at "
              f"rest {rest:.2f} s after the close")  # fmt: skip
        assert closed <= 1.5, closed
    finally:
        if d is not None:
            page.close()


def joints(client: PlanClient) -> tuple[np.ndarray, np.ndarray]:
    """arm0's latest (q, qd) on the test's bus client."""
    with client.recorder.lock:
        _, q, qd = client.recorder.joints["arm0"]
    return q.copy(), qd.copy()


def start_moving(client: PlanClient, path: np.ndarray) -> np.ndarray:
    """Execute the marked ``path`` again, from the test's own bus client (the page's Arm and
    Execute were tested above; pressing them costs ~10 s on a starved browser), and return
    the executed trajectory's last arm0 joints once the arm moves (2 mrad from where it was:
    the planner may run the path from the end the arm rests at, with no approach, and at
    the spot speed the joints move at ~5 mrad/s).
    A late planner heartbeat may refuse a request: tried 5 times (each refusal printed)."""
    for _ in range(5):
        q0 = joints(client)[0]
        try:
            plan = client.request(make_request(path, path=True, execute=True), 60.0)
        except RequestError as exc:
            print(f"\nexecute refused: {exc}")
            time.sleep(1.0)
            continue
        if plan.get("execution") != "accepted":
            print(f"\nexecute not accepted: {plan.get('execution_reason')}")
            time.sleep(1.0)
            continue
        wait_for(lambda q0=q0: float(np.max(np.abs(joints(client)[0] - q0))) > 2e-3, 30.0,
                 "the arm moving")  # fmt: skip
        return np.asarray(plan["trajectory"]["q"]["arm0"][-1], dtype=float)
    raise AssertionError("no execute moved the arm")


#: scrolls every scrolled box of the page to its end, then answers whether the big STOP
#: button is on screen and on top at its centre
BIG_STOP_ON_TOP = """
for (const e of document.querySelectorAll('*'))
  if (e.scrollHeight > e.clientHeight + 4) e.scrollTop = e.scrollHeight;
const b = document.getElementById(arguments[0]);
if (!b) return null;
const r = b.getBoundingClientRect();
const inside = r.left >= 0 && r.top >= 0 && r.right <= innerWidth && r.bottom <= innerHeight;
return inside && document.elementFromPoint((r.left + r.right) / 2, (r.top + r.bottom) / 2) === b
  ? b : null;
"""


def big_stop(d: Any) -> Any:
    """The page's big STOP button, after scrolling the panel to its end (where results
    push the panel's own STOP out of view): it must be on screen and on top."""
    from planner.console.hotkeys import BIG_STOP_ID

    b = d.execute_script(BIG_STOP_ON_TOP, BIG_STOP_ID)
    assert b is not None, "the big STOP is not on screen, on top, with the panel scrolled"
    return b


def stopped_by(d: Any, client: PlanClient, how: str, path: np.ndarray) -> tuple[float, float]:
    """Execute ``path`` again (:func:`start_moving`) and, while the arm moves, press STOP (``how`` =
    ``"button"``), press the space bar with the focus on the Execute button (``"space"``) or
    close the browser, the operator's only tab (``"close"``); seconds from
    the press or close to the console's STOP on the bus, and to the arm at rest (its joint
    speeds below 0.1 mrad/s; the treatment laser's gate then reported off); the button is the big STOP, with the panel scrolled to its end.
    Fails when the STOP reached the bus after the motion had ended:
    the joint states just before it at rest and the arm resting where the trajectory ends (a
    STOP in the still instant between the approach and the path stops the arm short of the
    end). A button press is tried 3 times."""
    from selenium.common.exceptions import WebDriverException
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    for attempt in range(1 if how == "close" else 3):
        stops = Inbox(client.session, client.keys.stop)
        states = Inbox(client.session, client.keys.joint_states("arm0"))
        laser = Inbox(client.session, client.keys.laser)
        try:
            stop_button = big_stop(d) if how == "button" else None
            if how == "space":
                d.execute_script("arguments[0].focus();", find_button(d, "Execute"))
            q_end = start_moving(client, path)
            t0 = time.monotonic()
            if how == "space":
                ActionChains(d).send_keys(Keys.SPACE).perform()
            elif stop_button is not None:
                try:
                    click_element(d, stop_button)
                except WebDriverException:  # re-rendered meanwhile: find it again
                    click_element(d, big_stop(d))
            else:
                d.quit()
            wait_for(lambda s=stops: s.bodies(), 10.0, f"STOP after the {how}")
            msg = stops.bodies()[0]
            reason = "last browser" if how == "close" else "operator pressed Stop"
            assert msg["source"] == "console" and reason in msg["reason"], msg
            t_stop = stops.times()[0]
            wait_for(lambda: float(np.max(np.abs(joints(client)[1]))) < 1e-4, 10.0,
                     f"the arm at rest after the {how}")  # fmt: skip
            rest = time.monotonic() - t0
            # the treatment laser is off once the arm rests: the gate's driver says so
            wait_for(lambda las=laser: las.bodies() and las.bodies()[-1]["on"] is False, 2.0,
                     f"the treatment laser reported off after the {how}")  # fmt: skip
            before = [np.max(np.abs(b["qd"])) for t, b in states.items
                      if t_stop - 0.05 <= t <= t_stop and isinstance(b, dict)]  # fmt: skip
            short = float(np.max(np.abs(joints(client)[0] - q_end)))  # rad from the end
            if (before and max(before) > 1e-3) or short > 2e-3:  # it was stopped mid-motion
                return t_stop - t0, rest
            print(f"\nSTOP by {how} came after the motion ended (attempt {attempt + 1}): "
                  f"{t_stop - t0:.2f} s after the {how}, joint speeds before it "
                  f"{max(before, default=0.0) * 1e3:.2f} mrad/s, rest {short * 1e3:.2f} mrad "
                  f"from the end")  # fmt: skip
        finally:
            stops.close()
            states.close()
            laser.close()
    raise AssertionError(f"the STOP by {how} never reached the bus while the arm moved")
