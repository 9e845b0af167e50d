"""localize_batch against a stand-in server: hloc's file conventions in, the submission and the
failure list out, in query order."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from fake_server import FakeServer, Received, response

from hscloc import Client
from hscloc.wire import pb

QUERIES = ["query/day/a.jpg", "query/night/b.jpg", "c.jpg", "d.jpg"]


def write_hloc_features(path: Path) -> None:
    with h5py.File(path, "w") as features:
        for index, name in enumerate(QUERIES):
            group = features.create_group(name)
            group["keypoints"] = np.array([[index, 10], [20, 30], [40, 50]], np.float32)
            group["descriptors"] = np.arange(8 * 3, dtype=np.float16).reshape(8, 3) / 24


def answer(_: int, call: Received) -> list[tuple[bytes, bytes]]:
    request = call.request.localize
    keypoints = np.frombuffer(request.keypoints, "<f4").reshape(-1, 2)
    descriptors = np.frombuffer(request.descriptors, "<f2").reshape(request.num_keypoints, -1)
    # The pose tells what was sent: the first keypoint, the descriptor type and layout.
    pose = pb.Pose(qw=1, tx=float(keypoints[0, 0]), ty=float(keypoints[0, 1]),
                   tz=float(descriptors[0, 1]) * 24 + request.descriptor_type)
    status = {"query/night/b.jpg": pb.INVALID_REQUEST, "c.jpg": pb.NOT_LOCALIZED}.get(
        request.query_name, pb.OK)
    localize = pb.LocalizeResponse(status=status, error_message="why" if status != pb.OK else "",
                                   cam_from_world=pose)
    return [(call.call_id, response(localize=localize))]


def test_localize_batch_writes_in_query_order_with_hlocs_conventions(tmp_path: Path) -> None:
    write_hloc_features(tmp_path / "features.h5")
    queries = tmp_path / "queries.txt"
    queries.write_text("".join(f"{name} PINHOLE 640 480 500 500 320 240\n" for name in QUERIES))
    out = tmp_path / "out" / "submission.txt"
    with FakeServer(answer) as server, Client(server.endpoint, timeout_s=5) as client:
        summary = client.localize_batch(queries, tmp_path / "features.h5", out, inflight=3)
        # At most one connection per request in flight (how many of them the batch needed
        # depends on how fast the answers came).
        assert 1 <= len({call.identity for call in server.received}) <= 3
    # Keypoints + 0.5 px; descriptors D x N transposed (the second value of descriptor 0 is
    # 3 / 24) and sent as stored (float16, wire type 1); b.jpg refused and not written; c.jpg
    # written and listed.
    assert out.read_text() == ("a.jpg 1 0 0 0 0.5 10.5 4\n"
                               "c.jpg 1 0 0 0 2.5 10.5 4\n"
                               "d.jpg 1 0 0 0 3.5 10.5 4\n")
    assert summary.failures_path.read_text() == ("b.jpg INVALID_REQUEST why\n"
                                                 "c.jpg NOT_LOCALIZED why\n")
    assert (summary.num_queries, summary.num_localized, summary.num_failed) == (4, 2, 2)


def test_localize_batch_checks_its_inputs_before_sending(tmp_path: Path) -> None:
    write_hloc_features(tmp_path / "features.h5")
    with FakeServer(answer) as server, Client(server.endpoint, timeout_s=5) as client:
        with pytest.raises(ValueError, match="no features for query 'e.jpg'"):
            client.localize_batch([("c.jpg", "PINHOLE 640 480 1 1 1 1"),
                                   ("e.jpg", "PINHOLE 640 480 1 1 1 1")],
                                  tmp_path / "features.h5", tmp_path / "out.txt")
        with pytest.raises(ValueError, match="inflight"):
            client.localize_batch([], tmp_path / "features.h5", tmp_path / "out.txt", inflight=0)
        assert server.received == []


def test_the_batch_module_does_not_import_the_client() -> None:
    # The client offers the batch (Client.localize_batch); the batch needs only what
    # LocalizingClient names, so the two modules import in one direction.
    import ast

    import hscloc.batch

    tree = ast.parse(Path(hscloc.batch.__file__).read_text())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    assert "client" not in imported
