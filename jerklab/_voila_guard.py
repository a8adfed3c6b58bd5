"""The class page's kernel websocket, guarded: only Voilà's own protocol, only well-formed frames.

A websocket to ``/api/kernels/<id>/channels`` without the ``v1.kernel.websocket.jupyter.org``
subprotocol falls back to jupyter_server's legacy format, whose binary frames start with a
count of buffers that the server believes: a count of 2**31 makes it build a 2**31-character
struct format, spinning at 100 % CPU with growing memory, deaf to SIGTERM, and every page of the
server freezes (an upstream bug). The v1 format has the same kind of count (8 bytes).

:class:`GuardedKernelConnection` is the kernel websocket connection of ``python -m jerklab.app``
(``--Voila.kernel_websocket_connection_class``) and of the students' servers on the hub
(``--ServerApp.kernel_websocket_connection_class``). It refuses, with HTTP 400 before the
upgrade, a websocket that does not offer the v1 subprotocol (Voilà's page and JupyterLab offer
it), and closes a websocket whose binary frame declares more parts than the frame can hold.
"""

from __future__ import annotations

from jupyter_server.services.kernels.connection.channels import ZMQChannelsWebsocketConnection
from tornado import web

__all__ = ["V1_PROTOCOL", "MAX_PARTS", "GuardedKernelConnection", "frame_problem"]

#: The subprotocol Voilà's page (and JupyterLab) offer for the kernel websocket.
V1_PROTOCOL = "v1.kernel.websocket.jupyter.org"

#: Parts of one kernel message in a v1 frame: channel, header, parent header, metadata,
#: content, then the buffers (a widget message carries a few).
MAX_PARTS = 1024


def frame_problem(frame):
    """Why a v1 binary frame is malformed (its declared offsets do not fit it), or None."""
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        return None  # text frames are parsed as JSON, bounded by the frame's size
    frame = bytes(frame)
    if len(frame) < 8:
        return f"a binary frame of {len(frame)} bytes has no offset count"
    n = int.from_bytes(frame[:8], "little")
    if n < 2 or n > MAX_PARTS or 8 * (n + 1) > len(frame):
        return f"a binary frame of {len(frame)} bytes declares {n} offsets"
    offsets = [int.from_bytes(frame[8 * (i + 1) : 8 * (i + 2)], "little") for i in range(n)]
    if any(o > len(frame) for o in offsets) or offsets != sorted(offsets):
        return "a binary frame's offsets point outside it"
    return None


class GuardedKernelConnection(ZMQChannelsWebsocketConnection):
    """jupyter_server's kernel websocket connection, v1 protocol only, malformed frames refused."""

    async def prepare(self):
        """Refuse (HTTP 400, before the upgrade) a websocket not offering the v1 subprotocol."""
        offered = self.websocket_handler.request.headers.get("Sec-WebSocket-Protocol", "")
        if V1_PROTOCOL not in [p.strip() for p in offered.split(",")]:
            self.log.warning("refused a kernel websocket without the %s subprotocol", V1_PROTOCOL)
            raise web.HTTPError(400, f"the kernel websocket needs the {V1_PROTOCOL} subprotocol")
        await super().prepare()

    def handle_incoming_message(self, incoming_msg):
        """Pass a well-formed frame on to the kernel; close the websocket on a malformed one."""
        if self.subprotocol != V1_PROTOCOL:
            why = "not the v1 protocol"
        elif not isinstance(incoming_msg, (bytes, bytearray, memoryview)):
            why = "a text frame on the v1 protocol"
        else:
            why = frame_problem(incoming_msg)
        if why is not None:
            self.log.warning("closed a kernel websocket: %s", why)
            self.websocket_handler.close(1003, "malformed kernel message")
            return
        super().handle_incoming_message(incoming_msg)
