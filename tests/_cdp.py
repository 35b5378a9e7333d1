"""Drive headless Chromium through the DevTools protocol (for the live-view tests and the
screenshots of docs/live.md): open a page, evaluate JavaScript in it, list every request it
made, take a screenshot. The websocket client is tornado's (installed with bokeh)."""

from __future__ import annotations

import asyncio
import base64
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-extensions", "--disable-default-apps", "--mute-audio"]


def chromium_path() -> str | None:
    """The Chromium binary (Debian's ``chromium``), or None."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


class Browser:
    """One headless Chromium with one page; ``evaluate`` runs a JavaScript expression and
    returns its JSON value."""

    def __init__(self, width: int = 1300, height: int = 1400):
        exe = chromium_path()
        if exe is None:
            raise RuntimeError("no chromium")
        self._dir = tempfile.TemporaryDirectory(prefix="openemt-cdp-", ignore_cleanup_errors=True)
        profile = Path(self._dir.name)
        self.proc = subprocess.Popen(
            [exe, *FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0",
             f"--window-size={width},{height}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = profile / "DevToolsActivePort"
        end = time.monotonic() + 60
        while not (port_file.exists() and len(port_file.read_text().split()) >= 2):
            if time.monotonic() > end or self.proc.poll() is not None:
                self.close()
                raise RuntimeError("chromium did not start its DevTools endpoint")
            time.sleep(0.05)
        port, path = port_file.read_text().split()[:2]
        self.loop = asyncio.new_event_loop()
        self._id = 0
        self.events: list = []
        self.requests: list = []
        self.ws = self._run(self._connect(f"ws://127.0.0.1:{port}{path}"))
        target = self.send("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.send("Target.attachToTarget", targetId=target,
                                 flatten=True)["sessionId"]
        self.send("Network.enable", session=True)
        self.send("Page.enable", session=True)
        self.send("Emulation.setDeviceMetricsOverride", session=True, width=width,
                  height=height, deviceScaleFactor=1, mobile=False)

    def _run(self, coro, timeout=60.0):
        return self.loop.run_until_complete(asyncio.wait_for(coro, timeout))

    async def _connect(self, url):
        from tornado.websocket import websocket_connect

        return await websocket_connect(url, max_message_size=256 * 1024 * 1024)

    async def _call(self, msg):
        await self.ws.write_message(json.dumps(msg))
        while True:
            raw = await self.ws.read_message()
            if raw is None:
                raise RuntimeError("chromium closed the DevTools connection")
            m = json.loads(raw)
            if m.get("method") == "Network.requestWillBeSent":
                self.requests.append(m["params"]["request"]["url"])
            if m.get("id") == msg["id"]:
                if "error" in m:
                    raise RuntimeError(f"{msg['method']}: {m['error']}")
                return m.get("result", {})

    def send(self, method, session=False, **params):
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        return self._run(self._call(msg))

    def open(self, url) -> None:
        self.send("Page.navigate", session=True, url=url)

    def evaluate(self, expression):
        r = self.send("Runtime.evaluate", session=True, expression=expression,
                      returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression[:80]}: {r['exceptionDetails']}")
        return r["result"].get("value")

    def wait_for(self, expression, timeout=60.0, interval=0.1):
        """Evaluate ``expression`` until it is truthy; its value."""
        end = time.monotonic() + timeout
        while True:
            try:
                v = self.evaluate(expression)
            except RuntimeError:
                v = None
            if v:
                return v
            if time.monotonic() > end:
                raise TimeoutError(f"waited {timeout} s for {expression[:120]}")
            time.sleep(interval)

    def screenshot(self, path, clip=None) -> None:
        kw = {"format": "png"}
        if clip is not None:
            kw["clip"] = dict(clip, scale=1)
        data = self.send("Page.captureScreenshot", session=True, **kw)["data"]
        Path(path).write_bytes(base64.b64decode(data))

    def close(self) -> None:
        try:
            if getattr(self, "ws", None) is not None:
                self.ws.close()
        finally:
            if self.proc.poll() is None:
                self.proc.terminate()
                try:
                    self.proc.wait(10)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(10)
            if hasattr(self, "loop"):
                self.loop.close()
            self._dir.cleanup()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


#: JavaScript: the data of the document's ColumnDataSource named NAME, as plain JSON.
SOURCE_JS = """(() => {{
  const doc = (window.Bokeh && Bokeh.documents && Bokeh.documents[0]) || null;
  if (!doc) return null;
  const m = doc.get_model_by_name({name!r});
  if (!m) return null;
  const out = {{}};
  const d = m.data;
  for (const [k, v] of (d instanceof Map ? d.entries() : Object.entries(d))) out[k] = Array.from(v, x => (ArrayBuffer.isView(x) ?
      Array.from(x) : x));
  return out;
}})()"""


def source_data(browser, name):
    """The data of the page's Bokeh ``ColumnDataSource`` named ``name`` (None before the
    document has arrived)."""
    return browser.evaluate(SOURCE_JS.format(name=name))
