"""A minimal headless-Chromium driver over the DevTools protocol (CDP), for the viewer's browser test.

Why not Playwright or Selenium: the Debian `chromium` package plus the `websockets` library (already installed with
uvicorn[standard]) are enough to load a page, type, click, read the DOM, collect console errors, save downloads and
take screenshots, with nothing downloaded at test time.
"""
from __future__ import annotations

import base64
import contextlib
import itertools
import json
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any
from urllib.request import urlopen

from websockets.sync.client import ClientConnection, connect

__all__ = ["CHROMIUM_FLAGS", "CdpConnection", "CdpError", "HeadlessChromium", "find_chromium"]

# Headless, no sandbox (runs as root in containers), no GPU, and no traffic of its own (updates, sync, QUIC probes).
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-dev-shm-usage", "--disable-extensions", "--mute-audio", "--hide-scrollbars",
    "--remote-debugging-port=0",
]


def find_chromium() -> str | None:
    """The Chromium binary (Debian's /usr/bin/chromium), or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class CdpError(RuntimeError):
    """A DevTools command failed, or a page script threw."""


class CdpConnection:
    """One DevTools websocket: numbered commands, their answers, and the events that arrive meanwhile."""

    def __init__(self, ws_url: str) -> None:
        self._ws: ClientConnection = connect(ws_url, max_size=None, open_timeout=10)
        self._ids = itertools.count(1)
        self.events: list[dict[str, Any]] = []

    def send(self, method: str, params: dict[str, Any] | None = None, timeout_s: float = 30.0) -> dict[str, Any]:
        message_id = next(self._ids)
        self._ws.send(json.dumps({"id": message_id, "method": method, "params": params or {}}))
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise CdpError(f"{method}: no answer within {timeout_s:g} s")
            message = json.loads(self._ws.recv(timeout=remaining))
            if message.get("id") == message_id:
                if "error" in message:
                    raise CdpError(f"{method}: {message['error']}")
                return message.get("result", {})
            if "method" in message:
                self.events.append(message)

    def drain(self, wait_s: float = 0.0) -> None:
        """Collects events that arrived while no command was waiting."""
        deadline = time.monotonic() + wait_s
        while True:
            try:
                message = json.loads(self._ws.recv(timeout=max(0.0, deadline - time.monotonic())))
            except TimeoutError:
                return
            if "method" in message:
                self.events.append(message)

    def close(self) -> None:
        self._ws.close()


class HeadlessChromium:
    """Chromium with a fresh profile, one page to drive, and downloads saved into `download_dir`."""

    def __init__(self, user_data_dir: Path, download_dir: Path, width: int = 1280, height: int = 800,
                 binary: str | None = None) -> None:
        binary = binary or find_chromium()
        if not binary:
            raise FileNotFoundError("chromium (install it with scripts/install_clients.sh)")
        self.user_data_dir = Path(user_data_dir)
        self.download_dir = Path(download_dir)
        self.download_dir.mkdir(parents=True, exist_ok=True)
        # the child keeps its own copy of the log's file descriptor: ours can be closed once it has started
        with open(self.user_data_dir.parent / "chromium.log", "wb") as log:
            self.process = subprocess.Popen(
                [binary, *CHROMIUM_FLAGS, f"--user-data-dir={self.user_data_dir}", f"--window-size={width},{height}",
                 "about:blank"], stdout=log, stderr=subprocess.STDOUT)
        port, browser_path = self._wait_for_devtools()
        self.browser = CdpConnection(f"ws://127.0.0.1:{port}{browser_path}")
        self.browser.send("Browser.setDownloadBehavior",
                          {"behavior": "allowAndName", "downloadPath": str(self.download_dir), "eventsEnabled": True})
        with urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as response:
            targets = json.loads(response.read())
        page = next(t for t in targets if t.get("type") == "page")
        self.page = CdpConnection(page["webSocketDebuggerUrl"])
        for domain in ("Page", "Runtime", "Log"):
            self.page.send(f"{domain}.enable")
        self.page.send("Emulation.setDeviceMetricsOverride",
                       {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})

    def _wait_for_devtools(self, timeout_s: float = 30.0) -> tuple[int, str]:
        """Chromium writes its DevTools port and browser path into the profile once it listens."""
        marker = self.user_data_dir / "DevToolsActivePort"
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise CdpError(f"chromium exited with code {self.process.returncode}")
            if marker.exists():
                lines = marker.read_text().split()
                if len(lines) >= 2:
                    return int(lines[0]), lines[1]
            time.sleep(0.05)
        raise CdpError(f"chromium did not open DevTools within {timeout_s:g} s")

    # ------------------------------------------------------------ page actions

    def navigate(self, url: str, timeout_s: float = 30.0) -> None:
        self.page.send("Page.navigate", {"url": url})
        self.wait_for("document.readyState === 'complete'", timeout_s)

    def evaluate(self, expression: str, timeout_s: float = 30.0) -> Any:
        """The value of a JavaScript expression in the page (promises awaited); raises if it throws."""
        result = self.page.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                     "awaitPromise": True}, timeout_s)
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            raise CdpError(f"{expression!r} threw: {details.get('exception', {}).get('description', details)}")
        return result.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout_s: float = 30.0, every_s: float = 0.1) -> Any:
        """Polls until the expression is truthy; returns its value."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"{expression!r} still falsy after {timeout_s:g} s")
            self.page.drain(every_s)

    def click(self, selector: str) -> None:
        """A real mouse click (press + release) at the centre of the element, as a user would do it."""
        box = self.evaluate(
            f"(() => {{ const el = document.querySelector({json.dumps(selector)}); if (!el) return null;"
            f" el.scrollIntoView({{block: 'center'}}); const r = el.getBoundingClientRect();"
            f" return [r.left + r.width / 2, r.top + r.height / 2]; }})()")
        if box is None:
            raise CdpError(f"no element matches {selector!r}")
        self.drag(box, box)

    def drag(self, start: tuple[float, float] | list[float], end: tuple[float, float] | list[float],
             steps: int = 1) -> None:
        """Mouse down at start, move to end in `steps`, mouse up (a click when start == end)."""
        x0, y0 = start
        x1, y1 = end
        self.page.send("Input.dispatchMouseEvent",
                       {"type": "mousePressed", "x": x0, "y": y0, "button": "left", "buttons": 1, "clickCount": 1})
        for i in range(1, steps + 1):
            x, y = x0 + (x1 - x0) * i / steps, y0 + (y1 - y0) * i / steps
            self.page.send("Input.dispatchMouseEvent",
                           {"type": "mouseMoved", "x": x, "y": y, "button": "left", "buttons": 1})
        self.page.send("Input.dispatchMouseEvent",
                       {"type": "mouseReleased", "x": x1, "y": y1, "button": "left", "buttons": 0, "clickCount": 1})

    def type_into(self, selector: str, text: str) -> None:
        """Focuses the element, selects its content and types `text` over it (real input events)."""
        found = self.evaluate(f"(() => {{ const el = document.querySelector({json.dumps(selector)});"
                              f" if (!el) return false; el.focus(); el.select(); return true; }})()")
        if not found:
            raise CdpError(f"no element matches {selector!r}")
        self.page.send("Input.insertText", {"text": text})

    def screenshot(self, path: Path) -> Path:
        data = self.page.send("Page.captureScreenshot", {"format": "png"})["data"]
        path = Path(path)
        path.write_bytes(base64.b64decode(data))
        return path

    def canvas_png(self, selector: str) -> bytes:
        """The canvas's own pixels (toDataURL), independent of what overlays it."""
        url = self.evaluate(f"document.querySelector({json.dumps(selector)}).toDataURL('image/png')")
        return base64.b64decode(url.split(",", 1)[1])

    def console_errors(self) -> list[str]:
        """Console errors, uncaught exceptions and error log entries (failed loads included) seen so far."""
        self.page.drain()
        errors = []
        for event in self.page.events:
            method, params = event["method"], event.get("params", {})
            if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                errors.append("console: " + " ".join(str(a.get("value", a.get("description")))
                                                    for a in params.get("args", [])))
            elif method == "Runtime.exceptionThrown":
                details = params.get("exceptionDetails", {})
                errors.append("exception: " + str(details.get("exception", {}).get("description", details)))
            elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
                entry = params["entry"]
                errors.append(f"log ({entry.get('source')}): {entry.get('text')} {entry.get('url', '')}")
        return errors

    def completed_downloads(self) -> dict[str, Path]:
        """Finished downloads: the name the page suggested -> the saved file (Chromium stores it under its GUID)."""
        self.browser.drain()
        names = {e["params"]["guid"]: e["params"].get("suggestedFilename", "")
                 for e in self.browser.events if e["method"] == "Browser.downloadWillBegin"}
        return {names.get(e["params"]["guid"], e["params"]["guid"]): self.download_dir / e["params"]["guid"]
                for e in self.browser.events
                if e["method"] == "Browser.downloadProgress" and e["params"].get("state") == "completed"}

    def close(self) -> None:
        for connection in (getattr(self, "page", None), getattr(self, "browser", None)):
            if connection is not None:
                with contextlib.suppress(Exception):  # the browser may already be gone; closing is best effort
                    connection.close()
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=5)
