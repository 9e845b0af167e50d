"""The exceptions of the hscloc client: one base class, one per way a call fails."""

from __future__ import annotations


class HsclocError(Exception):
    """Base class of every error the client raises about the server or the wire."""


class ServerTimeoutError(HsclocError, TimeoutError):
    """No reply came on any attempt (each on a fresh socket, to the next server): every attempt
    timed out, lost its connection or was refused, within the call's bound of `timeout_s`.

    Attributes:
        endpoint: the server (or the servers, comma-separated) tried.
        timeout_s: the bound that ran out.
        attempts: how many were made.
        detail: what became of each attempt.
    """

    def __init__(self, endpoint: str, timeout_s: float, attempts: int, detail: str = ""):
        super().__init__(
            f"{endpoint}: no reply within {timeout_s:g} s after {attempts} attempt"
            f"{'' if attempts == 1 else 's'}" + (f" ({detail})" if detail else "")
        )
        self.endpoint = endpoint
        self.timeout_s = timeout_s
        self.attempts = attempts
        self.detail = detail


class ServerError(HsclocError):
    """The server answered with a failure status (INVALID_REQUEST, OVERLOADED, UNAVAILABLE,
    INTERNAL, or one added to the protocol later).

    Attributes:
        status: the status's name in proto/hscloc.proto, e.g. "INVALID_REQUEST".
        message: the server's error message.
        query_name: the query the request was about ("" for health and info).
    """

    def __init__(self, status: str, message: str, query_name: str = ""):
        where = f"query '{query_name}': " if query_name else ""
        super().__init__(f"{where}server answered {status}" + (f": {message}" if message else ""))
        self.status = status
        self.message = message
        self.query_name = query_name


class ProtocolError(HsclocError):
    """A reply that is not an hscloc Response, or lacks the part the request asked for."""
