"""Localize requests from numpy arrays, checked before anything is sent."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .camera import CameraLike, as_camera
from .wire import pb

# The descriptor dtypes the wire carries, little-endian, and their wire names.
DESCRIPTOR_TYPES = {
    np.dtype("<f4"): pb.DESCRIPTOR_FLOAT32,
    np.dtype("<f2"): pb.DESCRIPTOR_FLOAT16,
}
MAX_TOP_K = 100


def _first_non_finite(array: np.ndarray) -> Optional[tuple[int, ...]]:
    bad = np.argwhere(~np.isfinite(array))
    return tuple(int(i) for i in bad[0]) if len(bad) else None


def check_keypoints(keypoints: np.ndarray) -> np.ndarray:
    """N x 2 pixels of any float dtype as little-endian float32 (the wire's); raises TypeError or
    ValueError naming `keypoints`."""
    keypoints = np.asarray(keypoints)
    if keypoints.dtype.kind != "f":
        raise TypeError(f"keypoints: dtype {keypoints.dtype}; expected float pixels (N x 2)")
    if keypoints.ndim != 2 or keypoints.shape[1] != 2:
        raise ValueError(f"keypoints: shape {keypoints.shape}; expected N x 2 (x, y in pixels)")
    keypoints = np.ascontiguousarray(keypoints, dtype="<f4")
    bad = _first_non_finite(keypoints)
    if bad is not None:
        raise ValueError(f"keypoints: keypoint {bad[0]} is not finite: {keypoints[bad[0]]}")
    return keypoints


def check_descriptors(descriptors: np.ndarray, num_keypoints: int) -> np.ndarray:
    """N x D float32 or float16 descriptors, little-endian and row-major as the wire wants them;
    raises TypeError or ValueError naming `descriptors`."""
    descriptors = np.asarray(descriptors)
    dtype = descriptors.dtype.newbyteorder("<")
    if dtype not in DESCRIPTOR_TYPES:
        raise TypeError(
            f"descriptors: dtype {descriptors.dtype}; the wire carries float32 or float16 "
            "(convert explicitly, e.g. descriptors.astype(np.float32))"
        )
    if descriptors.ndim != 2 or descriptors.shape[0] != num_keypoints or descriptors.shape[1] < 1:
        hint = ""
        if descriptors.ndim == 2 and descriptors.shape[1] == num_keypoints:
            hint = " (hloc's features.h5 stores D x N: pass descriptors.T)"
        raise ValueError(
            f"descriptors: shape {descriptors.shape}; expected N x D with N = {num_keypoints}, "
            f"one row per keypoint{hint}"
        )
    descriptors = np.ascontiguousarray(descriptors, dtype=dtype)
    bad = _first_non_finite(descriptors)
    if bad is not None:
        raise ValueError(
            f"descriptors: descriptor {bad[0]} is not finite (dimension {bad[1]}: "
            f"{descriptors[bad]})"
        )
    return descriptors


def check_global_descriptor(global_descriptor: np.ndarray) -> np.ndarray:
    """A G-vector of any float dtype as float32; raises TypeError or ValueError naming it."""
    global_descriptor = np.asarray(global_descriptor)
    if global_descriptor.dtype.kind != "f":
        raise TypeError(f"global_descriptor: dtype {global_descriptor.dtype}; expected floats")
    if global_descriptor.ndim != 1 or global_descriptor.size == 0:
        raise ValueError(f"global_descriptor: shape {global_descriptor.shape}; expected (G,)")
    global_descriptor = global_descriptor.astype(np.float32)
    bad = _first_non_finite(global_descriptor)
    if bad is not None:
        raise ValueError(f"global_descriptor: element {bad[0]} is not finite")
    return global_descriptor


@dataclass(frozen=True)
class LocalizeOptions:
    """Per-request overrides of the server's localizer options; None keeps the server's."""

    top_k: Optional[int] = None  # retrieved database images, 1..100
    visibility_filter: Optional[bool] = None  # drop matches to points the image does not see
    exhaustive: Optional[bool] = None  # pose every candidate, or stop at the first accepted

    def __post_init__(self) -> None:
        if self.top_k is not None:
            if isinstance(self.top_k, bool) or not isinstance(self.top_k, (int, np.integer)):
                raise TypeError(f"top_k: {self.top_k!r} is not an integer")
            if not 1 <= self.top_k <= MAX_TOP_K:
                raise ValueError(f"top_k: {self.top_k} is outside 1..{MAX_TOP_K}")

    def to_wire(self) -> pb.LocalizeOptions:
        options = pb.LocalizeOptions()
        if self.top_k is not None:
            options.top_k = int(self.top_k)
        if self.visibility_filter is not None:
            options.visibility_filter = bool(self.visibility_filter)
        if self.exhaustive is not None:
            options.exhaustive = bool(self.exhaustive)
        return options


def make_localize_request(keypoints: np.ndarray, descriptors: np.ndarray, camera: CameraLike, *,
                          global_descriptor: Optional[np.ndarray] = None,
                          options: LocalizeOptions = LocalizeOptions(), query_name: str = "",
                          map_id: str = "") -> pb.LocalizeRequest:
    """The wire request for one query (see Client.localize for the arguments); every array is
    checked here, so a bad one raises before anything is sent."""
    keypoints = check_keypoints(keypoints)
    descriptors = check_descriptors(descriptors, len(keypoints))
    request = pb.LocalizeRequest(
        request_id=query_name,
        map_id=map_id,
        query_name=query_name,
        camera=as_camera(camera).to_wire(),
        num_keypoints=len(keypoints),
        keypoints=keypoints.tobytes(),
        descriptor_dim=descriptors.shape[1],
        descriptor_type=DESCRIPTOR_TYPES[descriptors.dtype],
        descriptors=descriptors.tobytes(),
        options=options.to_wire(),
    )
    if global_descriptor is not None:
        request.global_descriptor.extend(check_global_descriptor(global_descriptor).tolist())
    return request
