"""Headless Chromium over the DevTools protocol: load a page, collect console errors, take a PNG.

Used by the tests and for the documentation screenshots. Chromium (Debian package ``chromium``)
is started with ``--headless --no-sandbox --disable-gpu`` and a throw-away profile; its DevTools
endpoint listens on 127.0.0.1 only. With ``--disable-gpu`` Chromium renders WebGL (the viewer)
in software through SwiftShader; ``--enable-unsafe-swiftshader`` keeps that fallback allowed in
Chromium versions that otherwise refuse it. The websocket client is ``websockets`` (a viser
dependency, i.e. the ``[viz]`` extra).
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
import urllib.request
from dataclasses import dataclass, field
from typing import Any

from skincal.errors import ConfigError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--hide-scrollbars",
    "--mute-audio",
)
_DEVTOOLS_LINE = re.compile(r"DevTools listening on (ws://[^\s]+)")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable (``$SKINCAL_CHROMIUM`` first), or None."""
    env = os.environ.get("SKINCAL_CHROMIUM")
    if env and shutil.which(env):
        return shutil.which(env)
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


@dataclass(frozen=True)
class PageCapture:
    """A rendered page: ``png`` bytes, the console/log errors (``console.error`` calls, uncaught
    exceptions, failed loads) and every console message, as one-line strings."""

    png: bytes
    errors: list[str] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)


class _Session:
    """Minimal synchronous DevTools client on one page target."""

    def __init__(self, ws_url: str) -> None:
        from websockets.sync.client import connect

        self._ws = connect(ws_url, max_size=None, open_timeout=10)
        self._next = 0
        self.events: list[dict[str, Any]] = []

    def call(self, method: str, timeout_s: float = 30.0, **params: Any) -> dict[str, Any]:
        self._next += 1
        ident = self._next
        self._ws.send(json.dumps({"id": ident, "method": method, "params": params}))
        deadline = time.monotonic() + timeout_s
        while True:
            msg = json.loads(self._ws.recv(timeout=max(0.01, deadline - time.monotonic())))
            if msg.get("id") == ident:
                if "error" in msg:
                    raise ConfigError(f"chromium: {method} failed: {msg['error'].get('message')}")
                return msg.get("result", {})
            self.events.append(msg)

    def pump(self, duration_s: float) -> None:
        """Collect events for ``duration_s`` seconds."""
        deadline = time.monotonic() + duration_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                self.events.append(json.loads(self._ws.recv(timeout=left)))
            except TimeoutError:
                return

    def close(self) -> None:
        self._ws.close()


def _describe(event: dict[str, Any]) -> tuple[str | None, str | None]:
    """(error text or None, message text or None) of one DevTools event."""
    method, p = event.get("method"), event.get("params", {})
    if method == "Runtime.consoleAPICalled":
        text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
        line = f"console.{p.get('type')}: {text}"
        return (line if p.get("type") in ("error", "assert") else None), line
    if method == "Runtime.exceptionThrown":
        d = p.get("exceptionDetails", {})
        text = d.get("exception", {}).get("description") or d.get("text", "exception")
        return f"uncaught: {text.splitlines()[0]}", None
    if method == "Log.entryAdded":
        e = p.get("entry", {})
        line = f"log.{e.get('level')}: {e.get('text')} {e.get('url', '')}".rstrip()
        return (line if e.get("level") == "error" else None), line
    return None, None


def capture_page(
    url: str,
    *,
    width: int = 1280,
    height: int = 800,
    ready_js: str | None = None,
    settle_s: float = 0.5,
    timeout_s: float = 30.0,
    chromium: str | None = None,
) -> PageCapture:
    """Load ``url`` in headless Chromium and screenshot it.

    Waits for the load event, then (when given) until the JavaScript expression ``ready_js`` is
    truthy, then ``settle_s`` more seconds, collecting console output throughout. Raises
    :class:`ConfigError` when Chromium is missing or the page does not get ready within ``timeout_s``.
    """
    exe = chromium or find_chromium()
    if exe is None:
        raise ConfigError("no Chromium found: install the Debian package 'chromium' or set SKINCAL_CHROMIUM")
    # Chromium's helper processes can still write into the profile for a moment after the browser
    # exits: clean-up must not turn a finished screenshot into an error.
    with tempfile.TemporaryDirectory(prefix="skincal-chromium-", ignore_cleanup_errors=True) as profile:
        args = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}",
                "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0", "about:blank"]
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            return _drive(proc, url, width, height, ready_js, settle_s, timeout_s)
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _devtools_port(proc: subprocess.Popen, timeout_s: float) -> int:
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            break
        m = _DEVTOOLS_LINE.search(line)
        if m:
            return int(m.group(1).split(":")[2].split("/")[0])
    raise ConfigError(f"chromium did not open its DevTools endpoint (exit code {proc.poll()})")


def _drive(
    proc: subprocess.Popen, url: str, width: int, height: int, ready_js: str | None, settle_s: float, timeout_s: float
) -> PageCapture:
    port = _devtools_port(proc, timeout_s)
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=timeout_s) as resp:
        targets = json.load(resp)
    page = next(t for t in targets if t.get("type") == "page")
    session = _Session(page["webSocketDebuggerUrl"])
    try:
        for domain in ("Page", "Runtime", "Log"):
            session.call(f"{domain}.enable")
        session.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1,
                     mobile=False)
        session.call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout_s
        while not any(e.get("method") == "Page.loadEventFired" for e in session.events):
            if time.monotonic() > deadline:
                raise ConfigError(f"chromium: {url} did not finish loading within {timeout_s:.0f} s")
            session.pump(0.1)
        while ready_js is not None:
            value = session.call("Runtime.evaluate", expression=ready_js, returnByValue=True)
            if value.get("result", {}).get("value"):
                break
            if time.monotonic() > deadline:
                raise ConfigError(f"chromium: {url} not ready ({ready_js}) within {timeout_s:.0f} s")
            session.pump(0.2)
        session.pump(settle_s)
        shot = session.call("Page.captureScreenshot", format="png")
        session.pump(0.05)
    finally:
        session.close()
    errors, messages = [], []
    for event in session.events:
        err, msg = _describe(event)
        if err:
            errors.append(err)
        if msg:
            messages.append(msg)
    return PageCapture(base64.b64decode(shot["data"]), errors, messages)
