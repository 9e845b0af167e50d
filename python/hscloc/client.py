"""The connection to an hscloc server: zguide's Lazy Pirate over a DEALER socket, failing over
between several equivalent servers (zguide's Freelance, all servers active), as the C++ client
does it (client/localization_client.h)."""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np
import zmq
from zmq.utils.monitor import recv_monitor_message

from .batch import BatchSummary, QueryInput, localize_batch
from .camera import CameraLike
from .errors import ProtocolError, ServerError, ServerTimeoutError
from .requests import LocalizeOptions, make_localize_request
from .results import Health, LocalizationResult, ServerInfo
from .wire import PROTOCOL_VERSION, RESULT_STATUSES, pb, status_name

# A Z85 CURVE key (40 characters), or the path of a file whose first line holds one
# (`hscloc keygen --out NAME` writes NAME.pub and NAME.key).
KeyLike = Union[str, bytes, os.PathLike]
Z85_KEY_LENGTH = 40


def read_curve_key(key: KeyLike, argument: str) -> bytes:
    """A Z85 key given as itself or as a key file; raises ValueError naming `argument`."""
    if isinstance(key, bytes):
        text = key.decode("ascii", errors="replace")
    elif isinstance(key, str) and len(key) == Z85_KEY_LENGTH and not os.path.exists(key):
        text = key
    else:
        path = Path(key)
        try:
            text = path.read_text().split("\n", 1)[0].strip()
        except OSError as error:
            raise ValueError(f"{argument}: cannot read a key from '{path}': {error}") from None
    if len(text) != Z85_KEY_LENGTH:
        raise ValueError(f"{argument}: a Z85 CURVE key has {Z85_KEY_LENGTH} characters, "
                         f"not {len(text)}")
    return text.encode("ascii")


@dataclass(frozen=True)
class ClientOptions:
    """Everything a connection is made from; a batch opens one connection per request in flight
    with the same options."""

    endpoints: tuple[str, ...]  # equivalent servers, tried in this order
    timeout_s: float  # per attempt
    retries: int  # attempts after the first that may time out, each on the next server
    curve_server_key: Optional[bytes]  # None: no encryption
    curve_public_key: Optional[bytes]
    curve_secret_key: Optional[bytes]


class Client:
    """A connection to `hscloc serve` (docs/protocol.md), or to several equivalent ones (the
    brokers of one deployment).

    A request goes to the current server. An attempt is given up on when that server's connection
    drops or is refused (at once), or when no reply comes within `timeout_s`; the socket is then
    closed, one to the next server connects, and the request is sent again (localize, health and
    info change nothing on the server). Timed-out attempts are allowed `retries` times after the
    first, and a call never takes more than (retries + 1) * timeout_s; then ServerTimeoutError is
    raised. Every request carries a call id that the server echoes, so that a late reply to an
    abandoned attempt is recognised and dropped. A failure status in the reply raises ServerError
    naming the status and the server's message.

    A Client is for one thread at a time; it is a context manager that closes its socket.

    Args:
        endpoint: the server, e.g. "tcp://localhost:5555", or a list of equivalent servers.
        timeout_s: seconds to wait for each attempt's reply.
        retries: attempts after the first that may time out.
        curve_server_key: the server's CURVE public key (or its .pub file): encrypts traffic.
        curve_client_keys: this client's (public, secret) CURVE keys (or their files), which the
            server's --curve-allowed-keys must list; generated when None.
    """

    def __init__(
        self,
        endpoint: Union[str, Sequence[str]],
        timeout_s: float = 10.0,
        retries: int = 2,
        curve_server_key: Optional[KeyLike] = None,
        curve_client_keys: Optional[tuple[KeyLike, KeyLike]] = None,
    ):
        endpoints = (endpoint,) if isinstance(endpoint, str) else tuple(endpoint)
        if not endpoints:
            raise ValueError("endpoint: no server given")
        for one in endpoints:
            if not isinstance(one, str) or not one:
                raise ValueError(f"endpoint: {one!r} is not a ZeroMQ endpoint")
        if not timeout_s > 0 or not math.isfinite(timeout_s):
            raise ValueError(f"timeout_s: {timeout_s} must be a positive number of seconds")
        if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
            raise ValueError(f"retries: {retries!r} must be an integer >= 0")
        public_key = secret_key = server_key = None
        if curve_server_key is not None:
            if not zmq.has("curve"):
                raise ValueError("curve_server_key: this libzmq has no CURVE support")
            server_key = read_curve_key(curve_server_key, "curve_server_key")
            if curve_client_keys is None:
                public_key, secret_key = zmq.curve_keypair()
            else:
                public_key = read_curve_key(curve_client_keys[0], "curve_client_keys[0]")
                secret_key = read_curve_key(curve_client_keys[1], "curve_client_keys[1]")
        elif curve_client_keys is not None:
            raise ValueError("curve_client_keys: given without curve_server_key")
        self._init(ClientOptions(endpoints, float(timeout_s), retries, server_key, public_key,
                                 secret_key))

    @classmethod
    def from_options(cls, options: ClientOptions) -> "Client":
        """A new connection with the options of another (see ClientOptions)."""
        client = cls.__new__(cls)
        client._init(options)
        return client

    def _init(self, options: ClientOptions) -> None:
        self.options = options
        self._context = zmq.Context()
        self._socket: Optional[zmq.Socket] = None
        self._monitor: Optional[zmq.Socket] = None
        self._current = 0
        self._next_call = 0
        self.failovers = 0  # requests resent to another server so far
        self._connect()

    @property
    def current_endpoint(self) -> str:
        """The server the next request goes to."""
        return self.options.endpoints[self._current]

    def _close_socket(self) -> None:
        # The socket stops reporting before its monitor closes: libzmq's I/O thread sends each
        # event with a blocking send, and one sent to a closed monitor (the old socket retrying a
        # dead server) would stall it, and every later socket of this client with it.
        if self._socket is not None:
            if self._monitor is not None:
                self._socket.disable_monitor()
            self._socket.close(linger=0)
            self._socket = None
        if self._monitor is not None:
            self._monitor.close(linger=0)
            self._monitor = None

    def _connect(self) -> None:
        self._close_socket()
        endpoint = self.current_endpoint
        socket = self._context.socket(zmq.DEALER)
        # A closed attempt's unsent request is dropped rather than delaying the exit.
        socket.linger = 0
        if self.options.curve_server_key is not None:
            socket.curve_serverkey = self.options.curve_server_key
            socket.curve_publickey = self.options.curve_public_key
            socket.curve_secretkey = self.options.curve_secret_key
        # The connection's events, so that a server that dies or refuses connections is left at
        # once rather than after the timeout.
        self._monitor = socket.get_monitor_socket(
            zmq.EVENT_CONNECTED | zmq.EVENT_DISCONNECTED | zmq.EVENT_CONNECT_RETRIED
            | zmq.EVENT_HANDSHAKE_SUCCEEDED)
        self._socket = socket
        # Whether the socket ever completed a handshake with its server: a connection that drops
        # after that lost a server that was there; one refused at the handshake (a CURVE key the
        # server does not admit) is reconnected by ZeroMQ and only the timeout gives up on it.
        self._connected = self._handshaken = False
        try:
            socket.connect(endpoint)
        except zmq.ZMQError as error:
            self._close_socket()
            raise ValueError(f"endpoint: cannot connect to '{endpoint}': {error}") from None

    def close(self) -> None:
        """Closes the socket; later calls raise."""
        self._close_socket()
        self._context.term()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def call(self, request: pb.Request) -> pb.Response:
        """Sends a wire Request (its protocol version set here) and returns the Response, with
        the failover, timeouts and retries above. A reload is never resent: its lost attempt
        raises ServerTimeoutError. Raises ServerTimeoutError or ProtocolError."""
        if self._socket is None:
            raise ValueError(f"client of {', '.join(self.options.endpoints)} is closed")
        request.protocol_version = PROTOCOL_VERSION
        payload = request.SerializeToString()
        resendable = request.WhichOneof("kind") != "reload"
        deadline = time.monotonic() + self.options.timeout_s * (self.options.retries + 1)
        outcomes: list[str] = []
        timeouts = failed_fast_in_a_row = 0  # failed fast: lost or refused connections
        while True:
            endpoint = self.current_endpoint
            timeout_s = min(self.options.timeout_s, deadline - time.monotonic())
            outcome, response = self._attempt(payload, timeout_s)
            if response is not None:
                return response
            outcomes.append(f"{endpoint} {outcome}")
            timeouts += outcome == "timed out"
            failed_fast_in_a_row = 0 if outcome == "timed out" else failed_fast_in_a_row + 1
            self._current = (self._current + 1) % len(self.options.endpoints)
            self._connect()  # Lazy Pirate: a fresh socket for whatever comes next
            if not resendable:
                raise ServerTimeoutError(endpoint, self.options.timeout_s, 1,
                                         f"{outcome}; a reload changes the server's state and is "
                                         "not resent: ask health() which map it serves")
            if timeouts > self.options.retries or time.monotonic() >= deadline:
                raise ServerTimeoutError(", ".join(self.options.endpoints),
                                         self.options.timeout_s * (self.options.retries + 1),
                                         len(outcomes), ", ".join(outcomes))
            self.failovers += 1
            if failed_fast_in_a_row >= len(self.options.endpoints):
                # Every server refused or dropped us: they may be restarting; wait a little
                # before the next round.
                time.sleep(max(0.0, min(0.1, deadline - time.monotonic())))

    def _attempt(self, payload: bytes, timeout_s: float) -> tuple[str, Optional[pb.Response]]:
        """One attempt: ("answered", the reply), or ("timed out" | "lost the connection" |
        "refused", None)."""
        assert self._socket is not None and self._monitor is not None
        self._next_call += 1
        call_id = str(self._next_call).encode()
        self._socket.send_multipart([call_id, payload])
        poller = zmq.Poller()
        poller.register(self._socket, zmq.POLLIN)
        poller.register(self._monitor, zmq.POLLIN)
        deadline = time.monotonic() + timeout_s
        while (left_s := deadline - time.monotonic()) > 0:
            ready = dict(poller.poll(max(1, math.ceil(left_s * 1000))))
            if self._monitor in ready:
                event = recv_monitor_message(self._monitor)["event"]
                self._connected = self._connected or event == zmq.EVENT_CONNECTED
                self._handshaken = self._handshaken or event == zmq.EVENT_HANDSHAKE_SUCCEEDED
                # A dropped connection loses the request; a refused one never carried it.
                if event == zmq.EVENT_DISCONNECTED and self._handshaken:
                    return "lost the connection", None
                if event == zmq.EVENT_CONNECT_RETRIED and not self._connected:
                    return "refused", None
            if self._socket not in ready:
                continue
            frames = self._socket.recv_multipart()
            if len(frames) != 2 or frames[0] != call_id:
                continue  # a late reply to an abandoned attempt
            response = pb.Response()
            try:
                response.ParseFromString(frames[1])
            except Exception as error:  # protobuf raises its DecodeError or a RuntimeWarning
                raise ProtocolError(
                    f"{self.current_endpoint}: the reply is not an hscloc Response ({error})"
                ) from None
            return "answered", response
        return "timed out", None

    def localize(
        self,
        keypoints: np.ndarray,
        descriptors: np.ndarray,
        camera: CameraLike,
        global_descriptor: Optional[np.ndarray] = None,
        top_k: Optional[int] = None,
        *,
        query_name: str = "",
        visibility_filter: Optional[bool] = None,
        exhaustive: Optional[bool] = None,
        map_id: str = "",
    ) -> LocalizationResult:
        """Localizes one query image from its local features.

        Args:
            keypoints: N x 2 pixels (x, y), COLMAP's convention: the centre of the top-left
                pixel is (0.5, 0.5). hloc's features.h5 puts it at (0, 0): add 0.5, or read
                with hscloc.read_hloc_features. Any float dtype; sent as float32.
            descriptors: N x D, one row per keypoint, float32 or float16 (sent as given; D must
                be the map's, see info()). hloc's features.h5 stores D x N: pass its transpose.
            camera: a hscloc.Camera, "MODEL WIDTH HEIGHT PARAMS..." or a pycolmap.Camera.
            global_descriptor: (G,) floats, for maps whose retrieval needs one.
            top_k: retrieved database images (1..100); None keeps the server's.
            query_name: names the query in the server's logs and in errors.
            visibility_filter: drop matches to points the retrieved image does not see; None
                keeps the server's setting.
            exhaustive: pose every candidate (True) or stop at the first with enough inliers.
            map_id: the map the server must serve ("" accepts any).

        Returns:
            The result, status "OK" or "NOT_LOCALIZED".

        Raises:
            TypeError, ValueError: a bad array or option, naming it, before anything is sent.
            ServerError: any other status, with the server's message.
            ServerTimeoutError: no reply after every attempt.
        """
        options = LocalizeOptions(top_k, visibility_filter, exhaustive)
        localize = make_localize_request(keypoints, descriptors, camera,
                                         global_descriptor=global_descriptor, options=options,
                                         query_name=query_name, map_id=map_id)
        response = self.call(pb.Request(localize=localize))
        if not response.HasField("localize"):
            # The envelope itself was refused (wrong version, undecodable).
            status = status_name(response.status or pb.INTERNAL)
            raise ServerError(status, response.error_message, query_name)
        status = status_name(response.localize.status)
        if status not in RESULT_STATUSES:
            raise ServerError(status, response.localize.error_message, query_name)
        return LocalizationResult.from_wire(response.localize, query_name)

    def health(self) -> Health:
        """The server's health, answered at once even when every worker is busy."""
        response = self._call_kind("health")
        return Health.from_wire(response.health)

    def info(self) -> ServerInfo:
        """The served map's description and the server's limits."""
        response = self._call_kind("info")
        return ServerInfo.from_wire(response.info, response.server_version)

    def _call_kind(self, kind: str) -> pb.Response:
        request = pb.Request()
        getattr(request, kind).SetInParent()
        response = self.call(request)
        if not response.HasField(kind):
            if response.status not in (pb.STATUS_UNSPECIFIED, pb.OK):
                raise ServerError(status_name(response.status), response.error_message)
            raise ProtocolError(f"{self.current_endpoint}: the reply to {kind} has no {kind}")
        return response

    def localize_batch(
        self,
        queries: QueryInput,
        features_h5: Union[str, os.PathLike],
        out: Union[str, os.PathLike],
        inflight: int = 16,
        *,
        descriptor_dtype: Optional[np.dtype] = None,
    ) -> BatchSummary:
        """Localizes a query list and writes the submission `hscloc localize` writes.

        Args:
            queries: an Aachen query list (NAME MODEL WIDTH HEIGHT PARAMS... per line), or a
                sequence of such lists or of (name, camera) pairs.
            features_h5: hloc features with a group per query name.
            out: the submission, NAME QW QX QY QZ TX TY TZ per query, in query order, with the
                image's basename; failures (status and message) go to `<out>.failures.txt`.
            inflight: requests in flight, one connection each.
            descriptor_dtype: None sends the descriptors as stored; np.float16 halves the bytes.

        Returns:
            The counts, as BatchSummary.

        Raises:
            ValueError: a malformed list, a query without features, a bad argument.
            ServerTimeoutError: the server does not answer; the batch stops.
        """
        return localize_batch(lambda: Client.from_options(self.options), queries, features_h5,
                              out, inflight, descriptor_dtype=descriptor_dtype)

