"""COLMAP cameras as the wire and the Aachen query lists describe them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence, Union

from .wire import pb


@dataclass(frozen=True)
class Camera:
    """A COLMAP camera: model name (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, ...),
    image size in pixels and the model's parameters. The server checks the model and the number
    of parameters."""

    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.model, str) or not self.model:
            raise ValueError(f"camera: model {self.model!r} is not a COLMAP model name")
        for field in ("width", "height"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                raise ValueError(f"camera: {field} {value!r} must be a positive integer")
        params = tuple(float(p) for p in self.params)
        bad = [p for p in params if not math.isfinite(p)]
        if bad:
            raise ValueError(f"camera: parameter {bad[0]} is not finite")
        object.__setattr__(self, "params", params)

    @classmethod
    def from_string(cls, text: str) -> "Camera":
        """Parses "MODEL WIDTH HEIGHT PARAMS...", e.g. "SIMPLE_RADIAL 1024 768 995 512 384 0.13"."""
        fields = text.split()
        try:
            params = tuple(float(f) for f in fields[3:])
            return cls(fields[0], int(fields[1]), int(fields[2]), params)
        except (IndexError, ValueError) as error:
            raise ValueError(
                f"camera '{text}': expected \"MODEL WIDTH HEIGHT PARAMS...\" ({error})"
            ) from None

    def to_wire(self) -> pb.Camera:
        return pb.Camera(model=self.model, width=self.width, height=self.height, params=self.params)


# A Camera, its text form, or an object with model, width, height and params attributes such as
# pycolmap.Camera (whose model may be an enum with a name).
CameraLike = Union[Camera, str, Any]


def as_camera(camera: CameraLike) -> Camera:
    """Any CameraLike as a Camera; raises ValueError or TypeError naming the camera."""
    if isinstance(camera, Camera):
        return camera
    if isinstance(camera, str):
        return Camera.from_string(camera)
    try:
        model = getattr(camera, "model_name", None) or camera.model
        params: Sequence[float] = camera.params
        return Camera(getattr(model, "name", model), int(camera.width), int(camera.height),
                      tuple(float(p) for p in params))
    except AttributeError:
        raise TypeError(
            f"camera: {type(camera).__name__} is neither a hscloc.Camera, a string "
            "\"MODEL WIDTH HEIGHT PARAMS...\" nor an object with model, width, height, params"
        ) from None
