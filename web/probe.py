"""A protocol-level viser client: what a browser tab receives, and when.

The dashboard's tests and benchmark need to see the websocket traffic itself
(update rates, the lag from an estimate to its arrival), which a rendered page
does not expose. This client speaks viser's wire protocol (its
``_infra._message_producer``): it connects with the ``viser-v<version>``
subprotocol and decodes each frame, ``[8 B msgpack size][8 B compressed
size][zstd(msgpack)][raw buffers]``, into the list of message dicts, each
with its ``type`` (``SetPositionMessage``, ``GuiUpdateMessage``, ...). It
listens, as a passive browser tab does, and can press buttons and move
sliders the way a tab does (:meth:`ViserProbe.set_gui`: the GuiUpdateMessage
a browser sends, msgpack-encoded, after the camera report that makes viser
count the tab as connected, :meth:`ViserProbe.announce_camera`).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator

import msgspec
import viser
import websockets
import zstandard
from websockets.asyncio.client import ClientConnection
from websockets.typing import Subprotocol

#: the camera report a browser tab sends first: viser counts a tab as connected (and runs its GUI
#: callbacks for it) only after one
CAMERA_REPORT = {
    "type": "ViewerCameraMessage",
    "wxyz": [1.0, 0.0, 0.0, 0.0],
    "position": [3.0, 3.0, 3.0],
    "fov": 1.0,
    "near": 0.01,
    "far": 1000.0,
    "image_height": 720,
    "image_width": 1280,
    "look_at": [0.0, 0.0, 0.0],
    "up_direction": [0.0, 0.0, 1.0],
}


class ViserProbe:
    """``async with ViserProbe(url) as p: async for t, messages in p.frames(): ...``"""

    def __init__(self, url: str, *, origin: str | None = "page") -> None:
        """``url``: the dashboard's page (its control address included: the websocket it names is
        the one opened); ``origin``: the ``Origin`` header sent, as a browser sends its page's
        (``"page"``: the dashboard's own; None: none, as a script sends)."""
        page, _, query = url.partition("?")
        params = dict(p.partition("=")[::2] for p in query.split("&") if p)
        self.url = params.get("websocket") or page.replace("http://", "ws://").replace("https://", "wss://")
        scheme, _, rest = page.partition("://")
        self.origin = f"{scheme}://{rest.split('/')[0]}" if origin == "page" else origin
        self._ws: ClientConnection | None = None
        self._dz = zstandard.ZstdDecompressor()
        self.frames_received = 0
        self.bytes_received = 0
        self._announced = False

    async def __aenter__(self) -> ViserProbe:
        self._ws = await websockets.connect(
            self.url,
            subprotocols=[Subprotocol(f"viser-v{viser.__version__}")],
            max_size=None,
            additional_headers={"Origin": self.origin} if self.origin else None,
        )
        return self

    @property
    def ws(self) -> ClientConnection:
        if self._ws is None:
            raise RuntimeError("ViserProbe is used outside its 'async with'")
        return self._ws

    async def __aexit__(self, *exc) -> None:
        await self.ws.close()

    def decode(self, raw: bytes) -> list[dict]:
        size, compressed = int.from_bytes(raw[0:8], "little"), int.from_bytes(raw[8:16], "little")
        inner = self._dz.decompress(raw[16 : 16 + compressed], max_output_size=size)
        return list(msgspec.msgpack.decode(inner)["messages"])

    async def announce_camera(self) -> None:
        """The first camera report a browser sends; viser counts a tab as connected
        (and runs its GUI callbacks) only after it."""
        await self.ws.send(msgspec.msgpack.encode(CAMERA_REPORT))

    async def set_gui(self, handle_id: str, **updates) -> None:
        """What a tab sends when a control changes (a button press is ``value=True``)."""
        if not self._announced:
            await self.announce_camera()
            self._announced = True
        await self.ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": handle_id, "updates": updates}))

    async def frames(self) -> AsyncIterator[tuple[float, list[dict]]]:
        """(receive time on ``time.monotonic``, messages) per websocket frame, until closed."""
        while True:
            try:
                raw = await self.ws.recv(decode=False)  # viser sends binary frames
            except websockets.ConnectionClosed:
                return
            t = time.monotonic()
            self.frames_received += 1
            self.bytes_received += len(raw)
            yield t, self.decode(raw)

    async def until_markdown(self, handle_id: str, text: str, timeout: float = 10.0) -> None:
        """Until a markdown element's content, as sent to this tab, says ``text`` (TimeoutError
        after ``timeout`` s)."""

        async def shown() -> None:
            async for _, messages in self.frames():
                for m in messages:
                    if m["type"] == "GuiUpdateMessage" and m.get("uuid") == handle_id:
                        if text in m["updates"].get("_markdown", ""):
                            return

        await asyncio.wait_for(shown(), timeout)

    async def until_notifications(self, title: str, count: int, timeout: float = 10.0) -> None:
        """Until ``count`` notifications titled ``title`` have been shown to this tab from now on
        (TimeoutError after ``timeout`` s): each press a panel refuses is told with one, so this
        waits until the presses were handled."""

        async def shown() -> None:
            seen = 0
            async for _, messages in self.frames():
                for m in messages:
                    if m["type"] == "NotificationShowMessage" and m["props"].get("title") == title:
                        seen += 1
                        if seen >= count:
                            return

        await asyncio.wait_for(shown(), timeout)


def gui_id(handle) -> str:
    """The id viser's GuiUpdateMessage carries for a GUI handle."""
    return handle._impl.uuid
