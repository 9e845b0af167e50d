"""What the server answers, as dataclasses with numpy arrays (poses as pycolmap prints them)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Optional, TypeVar

import numpy as np
from google.protobuf.message import Message

from .wire import pb, status_name


T = TypeVar("T")


def _from_same_names(cls: type[T], message: Message) -> T:
    """A dataclass whose fields are named as the message's."""
    return cls(**{f.name: getattr(message, f.name) for f in fields(cls)})


@dataclass(frozen=True, eq=False)
class Pose:
    """A rigid transform cam_from_world: x_cam = R(qvec) x_world + tvec (COLMAP's convention)."""

    qvec: np.ndarray  # (4,) unit quaternion, w first: (w, x, y, z)
    tvec: np.ndarray  # (3,) translation

    @classmethod
    def from_wire(cls, pose: pb.Pose) -> "Pose":
        # As sent: the server's quaternion is not renormalized, so that numbers stay bit for bit.
        return cls(
            qvec=np.array([pose.qw, pose.qx, pose.qy, pose.qz], dtype=np.float64),
            tvec=np.array([pose.tx, pose.ty, pose.tz], dtype=np.float64),
        )

    def rotmat(self) -> np.ndarray:
        """The 3 x 3 rotation matrix R of qvec."""
        w, x, y, z = self.qvec / np.linalg.norm(self.qvec)
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ])

    def center(self) -> np.ndarray:
        """The camera centre in world coordinates, -R^T t."""
        return -self.rotmat().T @ self.tvec

    def __repr__(self) -> str:
        return f"Pose(qvec={self.qvec.tolist()}, tvec={self.tvec.tolist()})"


@dataclass(frozen=True)
class StageTimings:
    """Milliseconds per stage of the server's localizer, and the server's total from receipt to
    reply (queueing and decoding included)."""

    retrieval_ms: float = 0.0
    match_ms: float = 0.0
    visibility_ms: float = 0.0
    pose_ms: float = 0.0
    total_ms: float = 0.0
    server_ms: float = 0.0
    votes_ms: float = 0.0
    refine_ms: float = 0.0
    rounds: int = 0

    @classmethod
    def from_wire(cls, timings: pb.StageTimings) -> "StageTimings":
        return _from_same_names(cls, timings)


@dataclass(frozen=True)
class Candidate:
    """A retrieved database image and what pose estimation made of it."""

    image_id: int
    image_name: str
    retrieval_score: float
    num_matches: int
    num_inliers: int
    evaluated: bool
    # "GLOBAL_DESCRIPTOR" (VLAD), "POINT_VOTES" (the network's votes) or "NEAREST_POINTS" (matched
    # to the points' mean descriptors where the network found no pose)
    source: str

    @classmethod
    def from_wire(cls, candidate: pb.Candidate) -> "Candidate":
        values = {f.name: getattr(candidate, f.name) for f in fields(cls)}
        values["source"] = pb.CandidateSource.Name(candidate.source)
        return cls(**values)


@dataclass(frozen=True)
class LocalizationResult:
    """The answer to one query.

    status is "OK" (cam_from_world is the pose, num_inliers its support) or "NOT_LOCALIZED"
    (well formed, but no candidate reached the minimum inliers; cam_from_world is then the top-1
    retrieved database image's pose, or None without one). Failure statuses raise ServerError.
    """

    query_name: str
    status: str
    cam_from_world: Optional[Pose]
    num_inliers: int
    retrieved_image_id: int
    retrieved_image_name: str
    failure_reason: str = ""  # why NOT_LOCALIZED, in the server's words
    candidates: list[Candidate] = field(default_factory=list)
    timings: StageTimings = field(default_factory=StageTimings)
    map_id: str = ""  # the map that answered ("<name>@<manifest hash>")

    @property
    def success(self) -> bool:
        return self.status == "OK"

    @classmethod
    def from_wire(cls, response: pb.LocalizeResponse, query_name: str) -> "LocalizationResult":
        return cls(
            query_name=query_name,
            status=status_name(response.status),
            cam_from_world=(Pose.from_wire(response.cam_from_world)
                            if response.HasField("cam_from_world") else None),
            num_inliers=response.num_inliers,
            retrieved_image_id=response.retrieved_image_id,
            retrieved_image_name=response.retrieved_image_name,
            failure_reason=response.error_message,
            candidates=[Candidate.from_wire(c) for c in response.candidates],
            timings=StageTimings.from_wire(response.timings),
            map_id=response.map_id,
        )


@dataclass(frozen=True)
class Health:
    """The server's health: status "OK" while serving, "UNAVAILABLE" while draining.

    Asked of a broker's admin endpoint, `worker_maps` lists the map each of its workers serves
    (two ids while a map update rolls over them)."""

    status: str
    map_id: str
    uptime_s: float
    queued_requests: int
    worker_maps: list[str] = field(default_factory=list)

    @classmethod
    def from_wire(cls, health: pb.HealthResponse) -> "Health":
        return cls(status_name(health.status), health.map_id, health.uptime_s,
                   health.queued_requests, [worker.map_id for worker in health.worker_status])


@dataclass(frozen=True)
class ServerInfo:
    """The served map and the server's limits."""

    map_id: str
    descriptor_dim: int
    num_images: int
    num_points: int
    global_descriptor_dim: int
    needs_global_descriptor: bool
    matcher: str
    max_keypoints: int
    workers: int
    server_version: str

    @classmethod
    def from_wire(cls, info: pb.InfoResponse, server_version: str) -> "ServerInfo":
        return cls(info.map_id, info.descriptor_dim, info.num_images, info.num_points,
                   info.global_descriptor_dim, info.needs_global_descriptor, info.matcher,
                   info.max_keypoints, info.workers, server_version)
