"""The space bar presses STOP, anywhere on the operator's page.

viser has no keyboard events, so the console adds a small script to the page it serves
(:func:`with_hotkeys` wraps viser's HTTP handler): a press of the space bar clicks the STOP
button, whatever has the focus, and is never delivered to anything else. A browser presses a
focused button on the space bar's release, so without this the space bar would press the
last button clicked (Execute, say) instead of stopping.
"""

from __future__ import annotations

import dataclasses
import gzip
from collections.abc import Callable
from typing import Any

#: the page's keyboard handler (capture phase: it runs before any widget sees the key)
SCRIPT = b"""<script>
(() => {
  const space = (e) => e.code === "Space" || e.key === " ";
  document.addEventListener("keydown", (e) => {
    if (!space(e)) return;
    e.preventDefault();
    e.stopImmediatePropagation();
    if (e.repeat) return;
    const stop = [...document.querySelectorAll("button")]
      .find((b) => b.textContent.trim() === "STOP");
    if (stop) stop.click();
  }, true);
  for (const kind of ["keyup", "keypress"])
    document.addEventListener(kind, (e) => {
      if (space(e)) { e.preventDefault(); e.stopImmediatePropagation(); }
    }, true);
})();
</script>"""


def inject(html: bytes) -> bytes:
    """``html`` with :data:`SCRIPT` before its last ``</body>`` (or at its end): viser's
    page carries its whole app as data in a head script, which may hold any bytes."""
    at = html.lower().rfind(b"</body>")
    return html + SCRIPT if at < 0 else html[:at] + SCRIPT + html[at:]


def with_hotkeys(inner: Callable[..., Any] | None) -> Callable[..., Any]:
    """A ``process_request`` answering like ``inner`` (viser's), with :data:`SCRIPT` in
    every HTML page it serves (gzip kept when viser compressed it)."""

    def process_request(connection: Any, request: Any) -> Any:
        response = inner(connection, request) if inner is not None else None
        if response is None or response.status_code != 200:
            return response
        if not str(response.headers.get("Content-Type", "")).startswith("text/html"):
            return response
        zipped = response.headers.get("Content-Encoding") == "gzip"
        html = gzip.decompress(response.body) if zipped else response.body
        body = gzip.compress(inject(html)) if zipped else inject(html)
        headers = response.headers.copy()
        del headers["Content-Length"]
        headers["Content-Length"] = str(len(body))
        return dataclasses.replace(response, headers=headers, body=body)

    return process_request
