"""The client's Lazy Pirate connection and its errors, against stand-in servers on loopback."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest
from fake_server import FakeServer, Received, response

from hscloc import Client, ProtocolError, ServerError, ServerTimeoutError
from hscloc.wire import pb

CAMERA = "PINHOLE 640 480 500 500 320 240"


def health_reply(call: Received, map_id: str = "city") -> list[tuple[bytes, bytes]]:
    return [(call.call_id, response(health=pb.HealthResponse(status=pb.OK, map_id=map_id)))]


def free_loopback_endpoint() -> str:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{probe.getsockname()[1]}"


def test_bad_arrays_raise_before_sending() -> None:
    keypoints = np.zeros((4, 2), np.float32)
    with FakeServer(lambda _, call: health_reply(call)) as server, \
            Client(server.endpoint, timeout_s=5) as client:
        for descriptors in (np.zeros((4, 8), np.float64), np.zeros((3, 8), np.float32),
                            np.full((4, 8), np.nan, np.float32)):
            with pytest.raises((TypeError, ValueError), match="descriptors"):
                client.localize(keypoints, descriptors, CAMERA)
        assert client.health().map_id == "city"
        # Only the health request reached the server.
        assert [call.request.WhichOneof("kind") for call in server.received] == ["health"]


def test_a_server_that_is_down_is_tried_until_the_calls_bound() -> None:
    endpoint = free_loopback_endpoint()
    start = time.monotonic()
    with Client(endpoint, timeout_s=0.2, retries=2) as client:
        with pytest.raises(ServerTimeoutError, match=f"{endpoint}: no reply within 0.6 s after "
                                                     "[0-9]+ attempts") as raised:
            client.health()
    assert time.monotonic() - start >= 0.55
    assert isinstance(raised.value, TimeoutError) and f"{endpoint} refused" in raised.value.detail


def test_a_silent_server_times_out_after_the_retries() -> None:
    with FakeServer(lambda index, call: []) as server, \
            Client(server.endpoint, timeout_s=0.2, retries=2) as client:
        with pytest.raises(ServerTimeoutError, match="after 3 attempts") as raised:
            client.health()
    assert raised.value.detail.count("timed out") == 3


def test_a_request_moves_to_the_next_server_when_its_server_dies() -> None:
    # The first server takes the request and closes without answering: its connection drops.
    dying = FakeServer(lambda index, call: [])
    with FakeServer(lambda _, call: health_reply(call, "second")) as second, \
            Client([dying.endpoint, second.endpoint], timeout_s=30) as client:
        def kill_when_received() -> None:
            while not dying.received:
                time.sleep(0.005)
            dying.close()
        killer = threading.Thread(target=kill_when_received)
        killer.start()
        start = time.monotonic()
        assert client.health().map_id == "second"
        killer.join()
        assert time.monotonic() - start < 5  # the connection's loss, not the 30 s timeout
        assert client.failovers == 1 and client.current_endpoint == second.endpoint
        # Later requests stay with the server that answered.
        assert client.health().map_id == "second"
        assert len(second.received) == 2


def test_a_reload_is_not_resent_to_another_server() -> None:
    with FakeServer(lambda index, call: []) as first, FakeServer(lambda _, call: []) as second, \
            Client([first.endpoint, second.endpoint], timeout_s=0.3, retries=3) as client:
        with pytest.raises(ServerTimeoutError, match="not resent"):
            client.call(pb.Request(reload=pb.ReloadRequest()))
        time.sleep(0.1)
        assert len(first.received) == 1 and second.received == []


def test_each_retry_sends_the_request_again_on_a_fresh_socket() -> None:
    # Silent twice, then an answer: the third attempt succeeds.
    with FakeServer(lambda index, call: health_reply(call) if index == 2 else []) as server, \
            Client(server.endpoint, timeout_s=0.3, retries=2) as client:
        assert client.health().status == "OK"
    assert len(server.received) == 3
    assert len({call.identity for call in server.received}) == 3
    assert len({call.call_id for call in server.received}) == 3
    assert len({call.request.SerializeToString() for call in server.received}) == 1


def test_late_replies_are_dropped_by_call_id() -> None:
    def handler(index: int, call: Received) -> list[tuple[bytes, bytes]]:
        if index == 0:
            return []  # the first attempt times out
        first = server.received[0]
        # On the new socket: a reply carrying the abandoned attempt's call id, then the answer.
        return [(first.call_id, response(health=pb.HealthResponse(map_id="late"))),
                *health_reply(call, "current")]

    with FakeServer(handler) as server, Client(server.endpoint, timeout_s=0.3, retries=1) as client:
        assert client.health().map_id == "current"
        # The next call is not confused by anything left over either.
        assert client.health().map_id == "current"


FAILURE_STATUSES = [name for name in pb.Status.keys()
                    if name not in ("STATUS_UNSPECIFIED", "OK", "NOT_LOCALIZED")]


@pytest.mark.parametrize("status", [*FAILURE_STATUSES, "STATUS_99"])
def test_each_failure_status_raises_naming_it_and_the_message(status: str) -> None:
    number = 99 if status == "STATUS_99" else pb.Status.Value(status)

    def handler(_: int, call: Received) -> list[tuple[bytes, bytes]]:
        localize = pb.LocalizeResponse(status=number, error_message="the reason")
        return [(call.call_id, response(localize=localize))]

    with FakeServer(handler) as server, Client(server.endpoint, timeout_s=5) as client:
        with pytest.raises(ServerError) as raised:
            client.localize(np.zeros((4, 2)), np.zeros((4, 8), np.float32), CAMERA,
                            query_name="q.jpg")
    assert (raised.value.status, raised.value.message) == (status, "the reason")
    assert str(raised.value) == f"query 'q.jpg': server answered {status}: the reason"


def test_a_refused_envelope_raises_its_status() -> None:
    def handler(_: int, call: Received) -> list[tuple[bytes, bytes]]:
        return [(call.call_id, response(pb.INVALID_REQUEST, "protocol version 2, I speak 1"))]

    with FakeServer(handler) as server, Client(server.endpoint, timeout_s=5) as client:
        with pytest.raises(ServerError, match="INVALID_REQUEST: protocol version 2"):
            client.localize(np.zeros((4, 2)), np.zeros((4, 8), np.float32), CAMERA)
        with pytest.raises(ServerError, match="INVALID_REQUEST"):
            client.info()


def test_not_localized_is_a_result_with_the_top_retrieved_pose() -> None:
    def handler(_: int, call: Received) -> list[tuple[bytes, bytes]]:
        localize = pb.LocalizeResponse(
            status=pb.NOT_LOCALIZED, error_message="7 inliers", retrieved_image_id=3,
            cam_from_world=pb.Pose(qw=1, tx=0.25), timings=pb.StageTimings(pose_ms=1.5))
        return [(call.call_id, response(localize=localize))]

    with FakeServer(handler) as server, Client(server.endpoint, timeout_s=5) as client:
        result = client.localize(np.zeros((4, 2)), np.zeros((4, 8), np.float16), CAMERA)
    assert not result.success and result.status == "NOT_LOCALIZED"
    assert result.failure_reason == "7 inliers" and result.retrieved_image_id == 3
    assert result.cam_from_world.qvec.tolist() == [1, 0, 0, 0]
    assert result.cam_from_world.tvec.tolist() == [0.25, 0, 0]
    assert result.timings.pose_ms == 1.5


def test_a_reply_that_is_no_response_raises_protocol_error() -> None:
    with FakeServer(lambda _, call: [(call.call_id, b"\xff\xff\xff")]) as server, \
            Client(server.endpoint, timeout_s=5) as client:
        with pytest.raises(ProtocolError, match="not an hscloc Response"):
            client.health()


def test_bad_client_arguments_raise_naming_them(tmp_path) -> None:
    with pytest.raises(ValueError, match="timeout_s"):
        Client("tcp://127.0.0.1:1", timeout_s=0)
    with pytest.raises(ValueError, match="retries"):
        Client("tcp://127.0.0.1:1", retries=-1)
    with pytest.raises(ValueError, match="endpoint: cannot connect to 'nowhere'"):
        Client("nowhere")
    short_key = tmp_path / "server.pub"
    short_key.write_text("tooshort\n")
    with pytest.raises(ValueError, match="curve_server_key: a Z85 CURVE key has 40 characters"):
        Client("tcp://127.0.0.1:1", curve_server_key=short_key)
    with pytest.raises(ValueError, match="curve_client_keys: given without curve_server_key"):
        Client("tcp://127.0.0.1:1", curve_client_keys=("a", "b"))
