"""Headless Chromium driven over the DevTools protocol, for the dashboard tests.

Real time, not ``--virtual-time-budget``: a live page must keep its websocket
alive on the real clock. Tests wait for what the page shows (text in the DOM),
then capture: no sleeps, no guessed delays.
"""

from __future__ import annotations

import asyncio
import base64
import json
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import websockets

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class Browser:
    def __init__(self, width: int = 1200, height: int = 900) -> None:
        self.profile = Path(tempfile.mkdtemp(prefix="gs-chromium-"))
        self.proc = subprocess.Popen(
            [
                CHROMIUM,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--enable-unsafe-swiftshader",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--no-first-run",
                f"--user-data-dir={self.profile}",
                f"--window-size={width},{height}",
                "--remote-debugging-port=0",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        self._ws = None
        self._id = 0

    async def __aenter__(self) -> Browser:
        port_file = self.profile / "DevToolsActivePort"
        deadline = time.monotonic() + 30
        while not port_file.exists() or not port_file.read_text().strip():
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise RuntimeError("chromium did not start its DevTools endpoint")
            await asyncio.sleep(0.05)
        port = int(port_file.read_text().split()[0])
        import urllib.request

        targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json").read())
        page = next(t for t in targets if t["type"] == "page")
        self._ws = await websockets.connect(page["webSocketDebuggerUrl"], max_size=64 * 1024 * 1024)
        return self

    async def __aexit__(self, *exc) -> None:
        if self._ws is not None:
            await self._ws.close()
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        shutil.rmtree(self.profile, ignore_errors=True)

    async def call(self, method: str, **params) -> dict:
        self._id += 1
        my_id = self._id
        await self._ws.send(json.dumps({"id": my_id, "method": method, "params": params}))
        while True:
            msg = json.loads(await self._ws.recv())
            if msg.get("id") == my_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    async def goto(self, url: str) -> None:
        await self.call("Page.navigate", url=url)

    async def wait_for_text(self, text: str, timeout: float = 30.0) -> None:
        """Until ``text`` is in the page's visible text (polling the DOM)."""
        deadline = time.monotonic() + timeout
        while True:
            r = await self.call(
                "Runtime.evaluate", expression="document.body ? document.body.innerText : ''", returnByValue=True
            )
            if text in r.get("result", {}).get("value", ""):
                return
            if time.monotonic() > deadline:
                raise AssertionError(f"the page never showed {text!r}")
            await asyncio.sleep(0.1)

    async def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page."""
        r = await self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return r.get("result", {}).get("value")

    async def click_button(self, text: str) -> None:
        """Click the page's button that reads ``text``, as a mouse click does (React's handler runs)."""
        found = await self.evaluate(
            f"(() => {{ const b = [...document.querySelectorAll('button')]"
            f".find(b => b.innerText.trim() === {json.dumps(text)}); if (b) b.click(); return !!b; }})()"
        )
        if not found:
            raise AssertionError(f"the page has no button {text!r}")

    async def key_on(self, selector: str, key: str, code: int) -> None:
        """Focus the element ``selector`` and press ``key`` (its Windows virtual-key ``code``) there."""
        if not await self.evaluate(
            f"(() => {{ const e = document.querySelector({json.dumps(selector)}); if (e) e.focus(); return !!e; }})()"
        ):
            raise AssertionError(f"the page has no {selector}")
        for kind in ("keyDown", "keyUp"):
            await self.call("Input.dispatchKeyEvent", type=kind, key=key, code=key, windowsVirtualKeyCode=code)

    async def screenshot(self, path: Path):
        import numpy as np
        from PIL import Image

        r = await self.call("Page.captureScreenshot", format="png")
        path.write_bytes(base64.b64decode(r["data"]))
        return np.asarray(Image.open(path).convert("RGB"), dtype=float)
