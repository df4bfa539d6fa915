"""STOP at every scroll position: a big button always on screen, and the space bar.

viser has no keyboard events and its panel scrolls, so the console adds a small script to
the page it serves (:func:`with_hotkeys` wraps viser's HTTP handler). A press of the space
bar clicks the panel's STOP button, whatever has the focus, and is never delivered to
anything else (a browser presses a focused button on the space bar's release, so without
this the space bar would press the last button clicked, Execute say, instead of stopping).
A big STOP button fixed to the window's lower-left corner, above everything, clicks it too,
wherever the panel is scrolled.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

#: id of the page's always-visible STOP button
BIG_STOP_ID = "beamrelay-stop"

#: the page's keyboard handler (capture phase: it runs before any widget sees the key) and
#: the big STOP button fixed to the window's lower-left corner, over everything: both click
#: the panel's STOP (whose callback publishes the stop)
SCRIPT = b"""<script>
(() => {
  const press = () => {
    const stop = [...document.querySelectorAll("button")]
      .find((b) => b.id !== "beamrelay-stop" && b.textContent.trim() === "STOP");
    if (stop) stop.click();
  };
  const space = (e) => e.code === "Space" || e.key === " ";
  document.addEventListener("keydown", (e) => {
    if (!space(e)) return;
    e.preventDefault();
    e.stopImmediatePropagation();
    if (!e.repeat) press();
  }, true);
  for (const kind of ["keyup", "keypress"])
    document.addEventListener(kind, (e) => {
      if (space(e)) { e.preventDefault(); e.stopImmediatePropagation(); }
    }, true);
  const big = document.createElement("button");
  big.id = "beamrelay-stop";
  big.textContent = "STOP";
  big.title = "Every robot brakes, laser off (or press the space bar)";
  big.style.cssText = "position:fixed;left:16px;bottom:16px;z-index:2147483647;" +
    "background:#e03131;color:#fff;font:bold 30px sans-serif;padding:16px 52px;" +
    "border:3px solid #fff;border-radius:12px;box-shadow:0 2px 14px rgba(0,0,0,.6);" +
    "cursor:pointer;";
  big.addEventListener("click", (e) => { e.preventDefault(); e.stopPropagation(); press(); });
  document.body.appendChild(big);
})();
</script>"""


def inject(html: bytes) -> bytes:
    """``html`` with :data:`SCRIPT` before its last ``</body>`` (or at its end): viser's
    page carries its whole app as data in a head script, which may hold any bytes."""
    at = html.lower().rfind(b"</body>")
    return html + SCRIPT if at < 0 else html[:at] + SCRIPT + html[at:]


def with_hotkeys(inner: Callable[..., Any] | None) -> Callable[..., Any]:
    """A ``process_request`` answering like ``inner`` (viser's), with :data:`SCRIPT` in
    every HTML page it serves. It asks ``inner`` for an uncompressed answer (the request's
    ``Accept-Encoding`` removed): viser's page is a small loader around its app, already
    zstd-compressed, so gzip took only 18 % off its 0.8 MB and cost a compression by viser
    plus a decompression and a compression again here, on every page load."""

    def process_request(connection: Any, request: Any) -> Any:
        if "Accept-Encoding" in request.headers:
            del request.headers["Accept-Encoding"]
        response = inner(connection, request) if inner is not None else None
        if response is None or response.status_code != 200:
            return response
        if not str(response.headers.get("Content-Type", "")).startswith("text/html"):
            return response
        body = inject(response.body)
        headers = response.headers.copy()
        del headers["Content-Length"]
        headers["Content-Length"] = str(len(body))
        return dataclasses.replace(response, headers=headers, body=body)

    return process_request
