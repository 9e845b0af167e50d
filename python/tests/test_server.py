"""The Python client against a real `hscloc serve` of the trained small city, on loopback,
beside the C++ tools: the same queries give the same numbers, bit for bit."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest
from harness import City, Tools, serve

from hscloc import (Client, ServerError, ServerTimeoutError, format_pose_line, read_hloc_features,
                    read_query_list)
from hscloc.batch import image_basename

pytestmark = pytest.mark.server


def run(*command: object) -> str:
    """Runs a tool, returns its output; fails the test with the output when it fails."""
    done = subprocess.run([str(c) for c in command], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True)
    assert done.returncode == 0, f"{command} exited {done.returncode}:\n{done.stdout}"
    return done.stdout


def read_lines(path: Path) -> dict[str, str]:
    return {line.split(" ", 1)[0]: line for line in path.read_text().splitlines(keepends=True)}


def test_health_and_info(server: str, city: City) -> None:
    with Client(server) as client:
        health = client.health()
        info = client.info()
    # "<directory name>@<manifest hash>"
    assert health.status == "OK" and re.fullmatch("map@[0-9a-f]{16}", health.map_id)
    assert info.map_id == health.map_id
    assert health.uptime_s >= 0
    with h5py.File(city.features) as features:
        name = read_query_list(city.day_queries)[0].name
        dimension = read_hloc_features(features, name).descriptors.shape[1]
    assert info.descriptor_dim == dimension
    assert info.num_images > 0 and info.num_points > 0 and info.workers == 2
    assert not info.needs_global_descriptor and info.server_version


@pytest.mark.parametrize("dtype", [np.float32, np.float16])
def test_results_equal_hscloc_clients_bit_for_bit(server: str, city: City, tools: Tools,
                                                  tmp_path: Path, dtype: type) -> None:
    # hscloc-client sends float16 unless told --float32; its global options after `batch`.
    submission = tmp_path / "client.txt"
    run(tools.hscloc_client, "batch", "--server", server,
        *(["--float32"] if dtype == np.float32 else []), "--queries", city.day_queries,
        "--queries", city.night_queries, "--features", city.features, "--out", submission,
        "--inflight", 2)
    expected = read_lines(submission)
    queries = read_query_list(city.day_queries) + read_query_list(city.night_queries)
    assert len(expected) == len(queries) == 100
    actual: dict[str, str] = {}
    num_localized = 0
    with Client(server) as client, h5py.File(city.features) as features:
        for query in queries:
            image = read_hloc_features(features, query.name)
            result = client.localize(image.keypoints, image.descriptors.astype(dtype),
                                     query.camera, query_name=query.name)
            num_localized += result.success
            basename = image_basename(query.name)
            actual[basename] = format_pose_line(basename, result.cam_from_world)
            numbers = [float(v) for v in expected[basename].split()[1:]]
            assert numbers == [*result.cam_from_world.qvec, *result.cam_from_world.tvec]
    assert actual == expected
    assert num_localized >= 80


def test_a_result_holds_pose_inliers_candidates_and_timings(server: str, city: City) -> None:
    query = read_query_list(city.day_queries)[0]
    with Client(server) as client, h5py.File(city.features) as features:
        image = read_hloc_features(features, query.name)
        result = client.localize(image.keypoints, image.descriptors, query.camera,
                                 query_name=query.name)
        top_2 = client.localize(image.keypoints, image.descriptors, query.camera, top_k=2)
    assert result.success and result.query_name == query.name
    assert re.fullmatch("map@[0-9a-f]{16}", result.map_id)  # the map that made the pose
    assert np.linalg.norm(result.cam_from_world.qvec) == pytest.approx(1, abs=1e-9)
    assert result.num_inliers >= 12
    best = max((c for c in result.candidates if c.evaluated), key=lambda c: c.num_inliers)
    assert (result.retrieved_image_id, result.retrieved_image_name) == (best.image_id,
                                                                        best.image_name)
    # The final pose is refined over the matches of every candidate that agrees with the winner,
    # so it has at least the winner's inliers.
    assert result.num_inliers >= best.num_inliers
    # The global descriptor's candidates come first; the network's votes follow only after them.
    sources = [c.source for c in result.candidates]
    assert sources[0] == "GLOBAL_DESCRIPTOR"
    assert sources == sorted(sources, key=["GLOBAL_DESCRIPTOR", "POINT_VOTES", "NEAREST_POINTS"].index)
    timings = result.timings
    assert min(timings.retrieval_ms, timings.match_ms, timings.pose_ms) > 0
    assert timings.server_ms >= timings.total_ms > 0
    assert len(top_2.candidates) == 2


def test_the_servers_refusals_raise_with_its_message(server: str, city: City) -> None:
    query = read_query_list(city.day_queries)[0]
    with Client(server) as client, h5py.File(city.features) as features:
        image = read_hloc_features(features, query.name)
        wider = np.hstack([image.descriptors, image.descriptors[:, :1]])
        with pytest.raises(ServerError, match="query 'wide.jpg': server answered "
                                              "INVALID_REQUEST: .*descriptor") as raised:
            client.localize(image.keypoints, wider, query.camera, query_name="wide.jpg")
        assert raised.value.status == "INVALID_REQUEST"
        with pytest.raises(ServerError, match="map 'elsewhere' requested"):
            client.localize(image.keypoints, image.descriptors, query.camera, map_id="elsewhere")


def test_curve_serves_an_allowed_key_and_refuses_another(tools: Tools, city: City,
                                                         tmp_path: Path) -> None:
    for name in ("server", "client", "stranger"):
        run(tools.hscloc, "keygen", "--out", tmp_path / name)
    allowed = tmp_path / "allowed.txt"
    allowed.write_text((tmp_path / "client.pub").read_text())
    query = read_query_list(city.day_queries)[0]
    with h5py.File(city.features) as features:
        image = read_hloc_features(features, query.name)
    with serve(tools, city.map, tmp_path / "serve.log", "--curve-secret-key",
               tmp_path / "server.key", "--curve-allowed-keys", allowed) as endpoint:
        client_keys = ((tmp_path / "client.pub").read_text().strip(), tmp_path / "client.key")
        with Client(endpoint, curve_server_key=tmp_path / "server.pub",
                    curve_client_keys=client_keys) as client:
            assert client.health().status == "OK"
            assert client.localize(image.keypoints, image.descriptors, query.camera).success
        stranger_keys = (tmp_path / "stranger.pub", tmp_path / "stranger.key")
        with Client(endpoint, timeout_s=1, retries=1, curve_server_key=tmp_path / "server.pub",
                    curve_client_keys=stranger_keys) as stranger:
            with pytest.raises(ServerTimeoutError, match="after 2 attempts"):
                stranger.health()
        with Client(endpoint, timeout_s=1, retries=0) as plain:
            with pytest.raises(ServerTimeoutError):
                plain.health()


def test_localize_batch_writes_hscloc_localizes_submission(server: str, city: City, tools: Tools,
                                                           tmp_path: Path) -> None:
    # One thread: `hscloc localize` then writes in query order, as localize_batch always does.
    offline = tmp_path / "offline.txt"
    run(tools.hscloc, "localize", "--map", city.map, "--queries", city.day_queries,
        "--queries", city.night_queries, "--features", city.features, "--out", offline,
        "--threads", 1)
    served = tmp_path / "served" / "submission.txt"
    with Client(server) as client:
        summary = client.localize_batch([city.day_queries, city.night_queries], city.features,
                                        served, inflight=4)
    assert served.read_bytes() == offline.read_bytes()
    assert summary.num_queries == 100
    assert summary.num_localized + summary.num_failed == 100
    failed = [line.split()[0] for line in summary.failures_path.read_text().splitlines()]
    assert failed == [line.split()[0] for line in
                      Path(f"{offline}.failures.txt").read_text().splitlines()]
    assert len(failed) == summary.num_failed


def test_localize_batch_names_a_query_without_features(server: str, city: City,
                                                       tmp_path: Path) -> None:
    with Client(server) as client:
        with pytest.raises(ValueError, match="no features for query 'nowhere.jpg'"):
            client.localize_batch([("nowhere.jpg", "PINHOLE 640 480 500 500 320 240")],
                                  city.features, tmp_path / "out.txt")
