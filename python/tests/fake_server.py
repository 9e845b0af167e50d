"""A stand-in server on a real loopback ROUTER socket whose answers a test chooses: for the
client's retries, late replies and statuses, which a healthy `hscloc serve` never shows."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Callable, Optional

import zmq

from hscloc.wire import pb


@dataclass(frozen=True)
class Received:
    identity: bytes  # the client socket's routing id: a new socket has a new one
    call_id: bytes
    request: pb.Request


# Given the index of a received request and the request, returns the replies to send as
# (call id, payload) pairs; an empty list leaves it unanswered.
Handler = Callable[[int, Received], list[tuple[bytes, bytes]]]


class FakeServer:
    """Runs `handler` on every request received on tcp://127.0.0.1:<free port>."""

    def __init__(self, handler: Handler):
        self._handler = handler
        self._context = zmq.Context()
        self._router = self._context.socket(zmq.ROUTER)
        self._router.linger = 0
        self._router.bind("tcp://127.0.0.1:*")
        self.endpoint: str = self._router.last_endpoint.decode()
        self.received: list[Received] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            if not self._router.poll(20):
                continue
            identity, call_id, payload = self._router.recv_multipart()
            received = Received(identity, call_id, pb.Request.FromString(payload))
            self.received.append(received)
            for reply_call_id, reply in self._handler(len(self.received) - 1, received):
                self._router.send_multipart([identity, reply_call_id, reply])

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self._router.close()
        self._context.term()

    def __enter__(self) -> "FakeServer":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def response(status: Optional[int] = None, message: str = "", **kinds: object) -> bytes:
    """A serialized Response with the given envelope status and message and kinds
    (localize=pb.LocalizeResponse(...), health=...)."""
    reply = pb.Response(protocol_version=1, server_version="fake", error_message=message, **kinds)
    if status is not None:
        reply.status = status
    return reply.SerializeToString()
