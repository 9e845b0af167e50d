"""Requests from numpy arrays, cameras, query lists and submission lines, without a server."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hscloc import Camera, Pose, format_pose_line, read_query_list
from hscloc.batch import format_number
from hscloc.requests import LocalizeOptions, make_localize_request
from hscloc.wire import pb

CAMERA = "SIMPLE_RADIAL 1024 768 995.5 512 384 0.13"


def features(n: int = 5, d: int = 8, dtype: type = np.float32) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    keypoints = rng.uniform(1, 700, (n, 2))
    return keypoints, rng.normal(size=(n, d)).astype(dtype)


@pytest.mark.parametrize("dtype, wire_type", [(np.float32, pb.DESCRIPTOR_FLOAT32),
                                               (np.float16, pb.DESCRIPTOR_FLOAT16)])
def test_descriptors_travel_in_their_dtype(dtype: type, wire_type: int) -> None:
    keypoints, descriptors = features(dtype=dtype)
    request = make_localize_request(keypoints, descriptors, CAMERA, query_name="q.jpg",
                                    options=LocalizeOptions(top_k=3))
    assert request.descriptor_type == wire_type
    assert (request.num_keypoints, request.descriptor_dim) == (5, 8)
    sent = np.frombuffer(request.descriptors, dtype=np.dtype(dtype).newbyteorder("<"))
    np.testing.assert_array_equal(sent.reshape(5, 8), descriptors)
    np.testing.assert_array_equal(np.frombuffer(request.keypoints, "<f4").reshape(5, 2),
                                  keypoints.astype(np.float32))
    assert request.options.top_k == 3 and not request.options.HasField("exhaustive")
    assert request.request_id == request.query_name == "q.jpg"
    assert list(request.camera.params) == [995.5, 512, 384, 0.13]


def test_non_contiguous_and_big_endian_arrays_are_packed_as_values() -> None:
    keypoints, descriptors = features(d=16)
    request = make_localize_request(keypoints[:, ::-1], descriptors[:, ::2].astype(">f4"), CAMERA)
    np.testing.assert_array_equal(np.frombuffer(request.descriptors, "<f4").reshape(5, 8),
                                  descriptors[:, ::2])
    np.testing.assert_array_equal(np.frombuffer(request.keypoints, "<f4").reshape(5, 2),
                                  keypoints[:, ::-1].astype(np.float32))


def with_nan(array: np.ndarray, index: tuple[int, int]) -> np.ndarray:
    array = array.copy()
    array[index] = np.nan
    return array


KEYPOINTS, DESCRIPTORS = features()
BAD_ARGUMENTS = {
    "keypoints N x 3": (dict(keypoints=np.zeros((5, 3))), ValueError, "keypoints: shape (5, 3)"),
    "keypoints int": (dict(keypoints=np.zeros((5, 2), int)), TypeError, "keypoints: dtype int"),
    "keypoint NaN": (dict(keypoints=with_nan(KEYPOINTS, (3, 1))), ValueError, "keypoint 3"),
    "keypoint inf": (dict(keypoints=np.full((5, 2), np.inf)), ValueError, "keypoint 0"),
    "descriptors D x N": (dict(descriptors=DESCRIPTORS.T.copy()), ValueError, "descriptors.T"),
    "descriptors of 4 keypoints": (dict(descriptors=DESCRIPTORS[:4]), ValueError, "N = 5"),
    "descriptors 1-D": (dict(descriptors=DESCRIPTORS.ravel()), ValueError, "descriptors: shape"),
    "descriptors float64": (dict(descriptors=DESCRIPTORS.astype(np.float64)), TypeError,
                            "descriptors: dtype float64"),
    "descriptors uint8": (dict(descriptors=DESCRIPTORS.astype(np.uint8)), TypeError,
                          "descriptors: dtype uint8"),
    "descriptor NaN": (dict(descriptors=with_nan(DESCRIPTORS, (2, 6))), ValueError,
                       "descriptor 2 is not finite (dimension 6"),
    "float16 inf": (dict(descriptors=np.full((5, 8), np.inf, np.float16)), ValueError,
                    "descriptor 0"),
    "global NaN": (dict(global_descriptor=np.array([0.5, np.nan])), ValueError,
                   "global_descriptor: element 1"),
    "global 2-D": (dict(global_descriptor=np.zeros((2, 2))), ValueError, "global_descriptor"),
    "top_k 0": (dict(top_k=0), ValueError, "top_k: 0"),
    "top_k 101": (dict(top_k=101), ValueError, "top_k: 101"),
    "top_k float": (dict(top_k=2.0), TypeError, "top_k"),
    "camera text": (dict(camera="PINHOLE 640"), ValueError, "camera 'PINHOLE 640'"),
    "camera size": (dict(camera=SimpleNamespace(model="PINHOLE", width=0, height=480,
                                                params=[1, 1, 1, 1])), ValueError,
                    "camera: width 0"),
    "camera NaN": (dict(camera="PINHOLE 640 480 500 nan 320 240"), ValueError, "not finite"),
    "camera object": (dict(camera=42), TypeError, "camera: int"),
}


@pytest.mark.parametrize("case", BAD_ARGUMENTS)
def test_bad_arguments_raise_naming_them(case: str) -> None:
    arguments, error, message = BAD_ARGUMENTS[case]
    call = dict(keypoints=KEYPOINTS, descriptors=DESCRIPTORS, camera=CAMERA) | arguments
    with pytest.raises(error, match=re.escape(message)):
        top_k = call.pop("top_k", None)
        make_localize_request(**call, options=LocalizeOptions(top_k=top_k))


def test_camera_from_text_and_from_pycolmap_like_objects() -> None:
    camera = Camera.from_string(CAMERA)
    assert camera == Camera("SIMPLE_RADIAL", 1024, 768, (995.5, 512.0, 384.0, 0.13))
    enum_model = SimpleNamespace(name="SIMPLE_RADIAL")  # pycolmap >= 0.5: an enum
    like = SimpleNamespace(model=enum_model, width=1024, height=768,
                           params=np.array([995.5, 512, 384, 0.13]))
    request = make_localize_request(KEYPOINTS, DESCRIPTORS, like)
    assert request.camera == camera.to_wire()


def test_pose_center_is_minus_r_transpose_t() -> None:
    angle = 0.3  # about z
    pose = Pose(np.array([np.cos(angle / 2), 0, 0, np.sin(angle / 2)]), np.array([1.0, 2, 3]))
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                         [0, 0, 1]])
    np.testing.assert_allclose(pose.rotmat(), rotation, atol=1e-15)
    np.testing.assert_allclose(pose.center(), -rotation.T @ [1, 2, 3], atol=1e-15)


def test_numbers_are_written_as_the_cpp_tools_write_them() -> None:
    # What fmt's "{}" (FormatPoseLine in scene/query_io.cc) prints for these doubles.
    expected = {1.0: "1", -0.0: "-0", 1e16: "1e+16", 1e-5: "1e-05", 0.1: "0.1",
                123456789.0: "123456789", 1e15: "1000000000000000", 1.5e16: "1.5e+16",
                2.5e-7: "2.5e-07", 1234567890123456.7: "1234567890123456.8", -3e22: "-3e+22",
                0.30000000000000004: "0.30000000000000004"}
    assert {value: format_number(value) for value in expected} == expected
    pose = Pose(np.array([1.0, 0, 0, 0]), np.array([0.5, -2, 1e-5]))
    assert format_pose_line("a.jpg", pose) == "a.jpg 1 0 0 0 0.5 -2 1e-05\n"


def test_query_lists_are_read_like_the_cpp_reader(tmp_path: Path) -> None:
    path = tmp_path / "queries.txt"
    path.write_text("# comment\n\nquery/day/a.jpg PINHOLE 640 480 500 500 320 240\r\n"
                    "  b.jpg SIMPLE_RADIAL 100 80 90 50 40 -0.01\n")
    queries = read_query_list(path)
    assert [q.name for q in queries] == ["query/day/a.jpg", "b.jpg"]
    assert queries[1].camera == Camera("SIMPLE_RADIAL", 100, 80, (90, 50, 40, -0.01))
    path.write_text("a.jpg PINHOLE 640 480 1 1 1 1\na.jpg PINHOLE 640 480 1 1 1 1\n")
    with pytest.raises(ValueError, match=r"queries.txt:2: 'a.jpg' appears twice"):
        read_query_list(path)
    path.write_text("a.jpg PINHOLE 640 480 1 x 1 1\n")
    with pytest.raises(ValueError, match=r"queries.txt:1: camera"):
        read_query_list(path)
