"""Headless chromium for the console's browser test: start it, count websocket traffic and
the page's frames, read the page, project world points into the canvas the way the page's
camera does."""

from __future__ import annotations

import contextlib
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

CHROMIUM = ("chromium", "chromium-browser", "google-chrome")
#: records every message batch the page receives from the server, from before it loads: (time
#: ms, bytes of binary data in it). viser reads its websocket in a Web Worker that posts the
#: decoded messages to the page, so the probe listens to the workers' messages. Also the start
#: (ms) of each of the page's first 4000 animation frames, in ``window.__raf``.
WS_PROBE = """
window.__ws = [];
window.__raf = [];
(function frame() {
  if (window.__raf.length >= 4000) return;
  window.__raf.push(performance.now());
  requestAnimationFrame(frame);
})();
function __binaryBytes(x, depth) {
  if (x == null || depth > 8) return 0;
  if (x instanceof ArrayBuffer) return x.byteLength;
  if (ArrayBuffer.isView(x)) return x.byteLength;
  if (typeof x !== "object") return 0;
  let n = 0;
  for (const k in x) n += __binaryBytes(x[k], depth + 1);
  return n;
}
const NativeWorker = window.Worker;
window.Worker = function (...args) {
  const w = new NativeWorker(...args);
  w.addEventListener("message", (e) => {
    window.__ws.push([performance.now(), __binaryBytes(e.data, 0)]);
  });
  return w;
};
window.Worker.prototype = NativeWorker.prototype;
"""
RAF_FPS = """
const done = arguments[arguments.length - 1];
let n = 0; const t0 = performance.now();
function f() { n++; if (performance.now() - t0 < arguments_ms) requestAnimationFrame(f);
               else done(n / ((performance.now() - t0) / 1000)); }
requestAnimationFrame(f);
"""


#: [ms the first message batch over arguments[0] bytes was handled, ms the frame after it
#: ended (the next frame's start)], on the page's clock (0 = navigation start), or null
FIRST_BIG_FRAME = """
const big = window.__ws.find(m => m[1] > arguments[0]);
const after = big ? window.__raf.filter(t => t > big[0]) : [];
return after.length >= 2 ? [big[0], after[1]] : null;
"""


def first_frame_after(d: Any, min_bytes: int) -> tuple[float, float] | None:
    """(s, s) from the page's navigation start to the first message batch over
    ``min_bytes`` bytes and to the end of the frame that drew it, or None before then: when
    the page drew it, apart from how slowly a starved browser answers the webdriver."""
    got = d.execute_script(FIRST_BIG_FRAME, min_bytes)
    return None if got is None else (1e-3 * float(got[0]), 1e-3 * float(got[1]))


def chromium_paths() -> tuple[str, str] | None:
    """(browser, chromedriver) executables, or None when either is missing."""
    browser = next((p for p in map(shutil.which, CHROMIUM) if p), None)
    driver = shutil.which("chromedriver")
    return (browser, driver) if browser and driver else None


#: niceness of the browser: its software rendering must not starve the system under test (an
#: operator's browser runs on its own machine or GPU)
BROWSER_NICE = 15
#: CPUs the browser may use at most, when this process may set a cgroup CPU quota (root):
#: rendering in software it takes every idle cycle, and a saturated 2-core virtual machine
#: stalls even its highest-priority processes (the planner's heartbeat) for 100+ ms. One core
#: leaves the other to the system (which idles at ~0.6 of a core). Measured on the page: 0.6
#: of a core draws 2.7 fps and answers a webdriver call in ~1.7 s, 1.0 draws 5.4 fps and
#: answers in ~0.9 s
BROWSER_CPUS = 1.0
CGROUP_CPU = (Path("/sys/fs/cgroup/cpu"), Path("/sys/fs/cgroup"))  # v1, v2


def browser_cgroup(cpus: float = BROWSER_CPUS) -> Path | None:
    """A cgroup (made once per process, removed at exit) whose CPU quota is ``cpus``, or
    None when none can be made here (not root, no cpu controller)."""
    import atexit
    import os

    period = 100_000
    for root in CGROUP_CPU:
        for stale in root.glob("beamrelay-browser-*"):  # of test runs that were killed
            if not (Path("/proc") / stale.name.rsplit("-", 1)[-1]).exists():
                _rmdir(stale)
        v1 = (root / "cpu.cfs_quota_us").exists()
        if not v1 and "cpu" not in _read(root / "cgroup.subtree_control"):
            continue
        group = root / f"beamrelay-browser-{os.getpid()}"
        try:
            group.mkdir(exist_ok=True)
            if v1:
                (group / "cpu.cfs_period_us").write_text(str(period))
                (group / "cpu.cfs_quota_us").write_text(str(round(cpus * period)))
            else:
                (group / "cpu.max").write_text(f"{round(cpus * period)} {period}")
        except OSError:
            continue
        atexit.register(_rmdir, group)
        return group
    return None


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""


def _rmdir(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.rmdir()


def nice_browser(browser: str) -> str:
    """A wrapper script running ``browser`` at :data:`BROWSER_NICE`, in the
    :func:`browser_cgroup` when there is one (made once per process)."""
    import os
    import tempfile

    path = Path(tempfile.gettempdir()) / f"beamrelay-nice-chromium-{os.getpid()}"
    if not path.exists():
        group = browser_cgroup()
        enter = f'echo $$ > "{group}/cgroup.procs" 2>/dev/null\n' if group else ""
        path.write_text(f'#!/bin/sh\n{enter}exec nice -n {BROWSER_NICE} "{browser}" "$@"\n')
        path.chmod(0o755)
    return str(path)


def open_browser(width: int = 1024, height: int = 700) -> Any:
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    paths = chromium_paths()
    assert paths is not None
    opts = Options()
    opts.binary_location = nice_browser(paths[0])
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
              f"--window-size={width},{height}", "--enable-unsafe-swiftshader",
              "--use-angle=swiftshader", "--ignore-gpu-blocklist"):  # fmt: skip
        opts.add_argument(a)
    d = webdriver.Chrome(options=opts, service=Service(paths[1]))
    calm(d)
    d.set_script_timeout(120)
    d.set_page_load_timeout(120)
    d.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": WS_PROBE})
    return d


def calm(d: Any) -> None:
    """Every process of the browser at niceness :data:`BROWSER_NICE` (chromium running as
    root raises its GPU process's priority itself; renderers start per page: call after
    ``d.get``)."""
    import psutil

    for p in psutil.Process(d.service.process.pid).children(recursive=True):
        with contextlib.suppress(psutil.Error):
            p.nice(BROWSER_NICE)


def screenshot(d: Any) -> np.ndarray:
    """The page as an H x W x 3 uint8 array."""
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(d.get_screenshot_as_png())).convert("RGB"))


def canvas_rect(d: Any) -> tuple[float, float, float, float]:
    """(left, top, width, height) in CSS px of the largest canvas (the 3D view)."""
    rects = d.execute_script(
        "return [...document.querySelectorAll('canvas')].map(c => {"
        "const r = c.getBoundingClientRect(); return [r.left, r.top, r.width, r.height];});"
    )
    return tuple(max(rects, key=lambda r: r[2] * r[3]))


def page_text(d: Any) -> str:
    return str(d.execute_script("return document.body.textContent;"))


#: the first button whose text is arguments[0], scrolled into view (one round trip: asking
#: each of the page's ~30 buttons for its text took 20-40 s with a starved browser)
FIND_BUTTON = """
const b = [...document.querySelectorAll('button')].find(b => b.textContent.trim() === arguments[0]);
if (b) b.scrollIntoView({block: 'center'});
return b || null;
"""


def find_button(d: Any, label: str) -> Any:
    """The button labelled ``label`` (scrolled into view)."""
    b = d.execute_script(FIND_BUTTON, label)
    if b is None:
        raise AssertionError(f"no button {label!r} on the page")
    return b


def click_element(d: Any, b: Any) -> None:
    """A real mouse click on element ``b`` (W3C pointer actions: move, press, release;
    chromedriver's element click took ~20 s on a starved page)."""
    from selenium.webdriver.common.action_chains import ActionChains

    ActionChains(d).move_to_element(b).click().perform()


def click_button(d: Any, label: str) -> None:
    """Click the button labelled ``label`` with a real mouse click."""
    t0 = time.monotonic()
    b = find_button(d, label)
    t1 = time.monotonic()
    click_element(d, b)
    if time.monotonic() - t0 > 2.0:
        print(
            f"\n  click on {label!r}: found in {t1 - t0:.1f} s, clicked in "
            f"{time.monotonic() - t1:.1f} s"
        )


def wait_text(d: Any, pred: Any, timeout: float, what: str) -> str:
    """The page text once ``pred`` holds (a wait over 2 s is printed: the test's phases)."""
    t0 = time.monotonic()
    end = t0 + timeout
    while time.monotonic() < end:
        text = page_text(d)
        if pred(text):
            if time.monotonic() - t0 > 2.0:
                print(f"\n  {time.monotonic() - t0:.1f} s waiting for {what}")
            return text
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout:g} s waiting for {what}; page:\n{page_text(d)}")


def render_fps(d: Any, seconds: float = 3.0) -> float:
    return float(d.execute_async_script(RAF_FPS.replace("arguments_ms", str(1e3 * seconds))))


def project(position: np.ndarray, look_at: np.ndarray, up: np.ndarray, fov: float,
            points: np.ndarray, width: float, height: float) -> np.ndarray:  # fmt: skip
    """Pixels (K x 2, from the canvas's top-left) of world points seen by a pinhole camera at
    ``position`` looking at ``look_at`` with ``up`` and vertical field of view ``fov`` (rad),
    as three.js's PerspectiveCamera projects them."""
    z = (look_at - position) / np.linalg.norm(look_at - position)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image down
    rel = np.atleast_2d(points) - position
    c = np.column_stack([rel @ x, rel @ y, rel @ z])
    f = 0.5 * height / np.tan(0.5 * fov)
    return np.column_stack([width / 2 + f * c[:, 0] / c[:, 2], height / 2 + f * c[:, 1] / c[:, 2]])


#: the displayed input labelled arguments[0], scrolled into view, or null (one round trip)
LABELLED = """
const lab = [...document.querySelectorAll('label')].find(l => l.textContent.trim() === arguments[0]);
const box = lab && document.getElementById(lab.htmlFor);
if (!box || box.offsetParent === null) return null;
box.scrollIntoView({block: 'center'});
return box;
"""


def labelled(d: Any, label: str, timeout: float = 30.0) -> Any:
    """The displayed input labelled ``label``, scrolled into view (waits while the panel is
    still being built or re-rendered)."""
    end = time.monotonic() + timeout
    while (box := d.execute_script(LABELLED, label)) is None:
        if time.monotonic() > end:
            raise AssertionError(f"no input labelled {label!r} on the page")
        time.sleep(0.2)
    return box


#: the displayed option of an open dropdown whose text is arguments[0], or null
FIND_OPTION = """
return [...document.querySelectorAll('[role=option]')].find(
  o => o.offsetParent !== null && o.textContent.trim() === arguments[0]) || null;
"""


#: s after which a dropdown that has not opened is clicked again
REOPEN = 5.0


def select_option(d: Any, label: str, value: str, timeout: float = 20.0) -> None:
    """Choose ``value`` in the dropdown labelled ``label`` the way a user does: open it,
    click the option (real mouse clicks: chromedriver's element click took ~8 s each on a
    starved page); waits until the input shows it."""
    box = labelled(d, label, timeout)
    click_element(d, box)
    end = time.monotonic() + timeout
    clicked = time.monotonic()
    while (option := d.execute_script(FIND_OPTION, value)) is None:
        if time.monotonic() > end:
            raise AssertionError(f"no option {value!r} in the {label!r} dropdown")
        if time.monotonic() - clicked > REOPEN:  # the click was lost (a starved page)
            click_element(d, labelled(d, label, timeout))
            clicked = time.monotonic()
        time.sleep(0.1)
    click_element(d, option)
    while box.get_attribute("value") != value:
        if time.monotonic() > end:
            raise AssertionError(f"the {label!r} dropdown shows {box.get_attribute('value')!r}")
        time.sleep(0.1)


#: the page's largest canvas element (the 3D view)
LARGEST_CANVAS = """
return [...document.querySelectorAll('canvas')].reduce(
  (a, c) => (c.clientWidth * c.clientHeight > a.clientWidth * a.clientHeight ? c : a));
"""


def click_world_point(d: Any, view: Any, rect: tuple[float, float, float, float],
                      p: np.ndarray) -> None:  # fmt: skip
    """Click the canvas where the page's starting camera ``view`` sees world point ``p``."""
    from selenium.webdriver.common.action_chains import ActionChains

    # one round trip (asking each canvas for its size took ~1 s each)
    canvas = d.execute_script(LARGEST_CANVAS)
    u, v = project(view.position, view.look_at, view.up, view.fov, p, rect[2], rect[3])[0]
    ActionChains(d).move_to_element_with_offset(
        canvas, round(float(u) - rect[2] / 2), round(float(v) - rect[3] / 2)
    ).click().perform()


#: the innermost displayed element whose whole text is arguments[0] (a folder's title),
#: scrolled into view, or null
FIND_TEXT = """
const all = [...document.querySelectorAll('body *')].filter(
  e => e.offsetParent !== null && e.textContent.trim() === arguments[0]);
const inner = all.filter(e => !all.some(o => o !== e && e.contains(o)));
if (inner.length) inner[0].scrollIntoView({block: 'center'});
return inner[0] || null;
"""


def open_folder(d: Any, title: str, first_input: str, timeout: float = 30.0) -> None:
    """Open the collapsed GUI folder ``title`` with a real click on its title; waits until
    its input labelled ``first_input`` shows."""
    end = time.monotonic() + timeout
    while (head := d.execute_script(FIND_TEXT, title)) is None:
        if time.monotonic() > end:
            raise AssertionError(f"no folder {title!r} on the page")
        time.sleep(0.2)
    if d.execute_script(LABELLED, first_input) is None:
        click_element(d, head)
    labelled(d, first_input, max(end - time.monotonic(), 1.0))


def set_number(d: Any, label: str, value: float, timeout: float = 20.0) -> None:
    """Type ``value`` into the number input labelled ``label`` as a user does (select what
    is there, type, Tab away); waits until the input shows it."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    box = labelled(d, label, timeout)
    click_element(d, box)
    ActionChains(d).key_down(Keys.CONTROL).send_keys("a").key_up(Keys.CONTROL).perform()
    ActionChains(d).send_keys(f"{value:g}").send_keys(Keys.TAB).perform()
    end = time.monotonic() + timeout
    while _number(box.get_attribute("value")) != value:
        if time.monotonic() > end:
            raise AssertionError(f"the {label!r} input shows {box.get_attribute('value')!r}")
        time.sleep(0.1)


def _number(text: str | None) -> float | None:
    try:
        return float(text or "")
    except ValueError:
        return None
