"""Query lists in, submissions out: the Aachen formats and hloc's features.h5, and a batch that
localizes a list through the server with several requests in flight."""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Optional, Protocol, Sequence, Union

import numpy as np

from .camera import Camera, CameraLike, as_camera
from .errors import ServerError
from .results import LocalizationResult, Pose

if TYPE_CHECKING:
    import h5py

PathLike = Union[str, os.PathLike]


class LocalizingClient(Protocol):
    """What a batch needs of a connection (hscloc.Client is one): the batch depends on this, not
    on the client module, which offers the batch as Client.localize_batch."""

    def localize(self, keypoints: np.ndarray, descriptors: np.ndarray, camera: CameraLike, *,
                 query_name: str = "") -> LocalizationResult: ...

    def close(self) -> None: ...

# hloc puts the centre of the top-left pixel at (0, 0), COLMAP and the wire at (0.5, 0.5).
HLOC_TO_COLMAP_SHIFT_PX = np.float32(0.5)


@dataclass(frozen=True)
class Query:
    """A query image of a list: its name (as in the features file) and its camera."""

    name: str
    camera: Camera


# A query list, or a sequence of query lists, Query objects or (name, camera) pairs.
QueryInput = Union[PathLike, Sequence[Union[PathLike, Query, tuple[str, CameraLike]]]]


def read_query_list(path: PathLike) -> list[Query]:
    """Reads "NAME MODEL WIDTH HEIGHT PARAMS..." lines; blank lines and '#' comments are
    skipped. Raises ValueError naming the file and line."""
    queries: list[Query] = []
    lines_of: dict[str, int] = {}
    with open(path, encoding="utf-8") as file:
        for number, line in enumerate(file, start=1):
            fields = line.split()
            if not fields or fields[0].startswith("#"):
                continue
            where = f"{path}:{number}"
            if len(fields) < 4:
                raise ValueError(f"{where}: expected NAME MODEL WIDTH HEIGHT PARAMS...")
            name = fields[0]
            if name in lines_of:
                raise ValueError(
                    f"{where}: '{name}' appears twice (first on line {lines_of[name]})")
            lines_of[name] = number
            try:
                camera = Camera.from_string(" ".join(fields[1:]))
            except ValueError as error:
                raise ValueError(f"{where}: {error}") from None
            queries.append(Query(name, camera))
    return queries


def as_queries(queries: QueryInput) -> list[Query]:
    """Any QueryInput as a list of Query."""
    if isinstance(queries, (str, os.PathLike)):
        return read_query_list(queries)
    result: list[Query] = []
    for entry in queries:
        if isinstance(entry, (str, os.PathLike)):
            result.extend(read_query_list(entry))
        elif isinstance(entry, Query):
            result.append(entry)
        else:
            name, camera = entry
            result.append(Query(str(name), as_camera(camera)))
    return result


@dataclass(frozen=True, eq=False)
class Features:
    """One image's local features, ready for Client.localize."""

    keypoints: np.ndarray  # N x 2 float32 pixels, COLMAP's convention (top-left centre 0.5, 0.5)
    descriptors: np.ndarray  # N x D, float16 as stored, else float32


def read_hloc_features(features: h5py.Group, name: str) -> Features:
    """The features of image `name` in an hloc features file (a group per image holding
    `keypoints` N x 2 and `descriptors` D x N), read as `hscloc localize` reads them: keypoints
    shifted by 0.5 px to COLMAP's convention, descriptors transposed to N x D. Raises KeyError or
    ValueError naming the file and the image."""
    where = f"{features.file.filename}: image '{name}'"
    if name not in features or "keypoints" not in features[name]:
        raise KeyError(f"{where}: no group holding keypoints")
    group = features[name]
    if "descriptors" not in group:
        raise ValueError(f"{where}: no descriptors")
    keypoints = np.asarray(group["keypoints"][()])
    descriptors = np.asarray(group["descriptors"][()])
    if keypoints.ndim != 2 or keypoints.shape[1] != 2:
        raise ValueError(f"{where}: keypoints of shape {keypoints.shape}, expected N x 2")
    if descriptors.ndim != 2 or descriptors.shape[1] != len(keypoints):
        raise ValueError(f"{where}: descriptors of shape {descriptors.shape}, expected D x "
                         f"{len(keypoints)} (one column per keypoint)")
    stored_as_half = descriptors.dtype.kind == "f" and descriptors.itemsize == 2
    dtype = np.float16 if stored_as_half else np.float32
    return Features(
        keypoints=keypoints.astype(np.float32) + HLOC_TO_COLMAP_SHIFT_PX,
        descriptors=np.ascontiguousarray(descriptors.T, dtype=dtype),
    )


def format_number(value: float) -> str:
    """The shortest text that reads back as the same double, as fmt's "{}" writes it (the C++
    tools): 1 and -0 without ".0"."""
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def image_basename(name: str) -> str:
    """The image name without its directories, as visuallocalization.net submissions name it."""
    return name.rsplit("/", 1)[-1]


def format_pose_line(name: str, cam_from_world: Pose) -> str:
    """A submission line "NAME QW QX QY QZ TX TY TZ\\n", numbers as `hscloc localize` writes
    them."""
    numbers = [*cam_from_world.qvec.tolist(), *cam_from_world.tvec.tolist()]
    return " ".join([name, *map(format_number, numbers)]) + "\n"


@dataclass
class BatchSummary:
    num_queries: int = 0
    num_localized: int = 0
    # Not localized (still written, with the top-1 retrieved image's pose) or refused (not
    # written); all are listed in failures_path.
    num_failed: int = 0
    failures_path: Path = Path()
    seconds: float = 0.0


# What localizing one query gave: a result, or the server's refusal.
Outcome = Union[LocalizationResult, ServerError]


class _SubmissionWriter:
    """The submission and its failure list, as `hscloc localize` writes them, line by line."""

    def __init__(self, out: Path, summary: BatchSummary):
        out.parent.mkdir(parents=True, exist_ok=True)
        self._submission = open(out, "w", encoding="utf-8")
        self._failures = open(summary.failures_path, "w", encoding="utf-8")
        self._summary = summary

    def write(self, query: Query, outcome: Outcome) -> None:
        basename = image_basename(query.name)
        if isinstance(outcome, ServerError):
            status, message = outcome.status, outcome.message
        else:
            status, message = outcome.status, outcome.failure_reason
            if outcome.cam_from_world is not None:
                # As `hscloc localize`: a failed query gets the top-1 retrieved image's pose.
                self._submission.write(format_pose_line(basename, outcome.cam_from_world))
                self._submission.flush()
        if status == "OK":
            self._summary.num_localized += 1
        else:
            self._summary.num_failed += 1
            self._failures.write(f"{basename} {status} {message}\n")
            self._failures.flush()

    def close(self) -> None:
        self._submission.close()
        self._failures.close()


def localize_batch(
    make_client: Callable[[], LocalizingClient],
    queries: QueryInput,
    features_h5: PathLike,
    out: PathLike,
    inflight: int = 16,
    *,
    descriptor_dtype: Optional[np.dtype] = None,
) -> BatchSummary:
    """Client.localize_batch, with `make_client` opening each in-flight connection."""
    if isinstance(inflight, bool) or not isinstance(inflight, int) or inflight < 1:
        raise ValueError(f"inflight: {inflight!r} must be an integer >= 1")
    if descriptor_dtype is not None and np.dtype(descriptor_dtype) not in (np.float16, np.float32):
        raise ValueError(f"descriptor_dtype: {descriptor_dtype}; expected float16 or float32")
    import h5py  # only the batch and read_hloc_features's callers need it

    query_list = as_queries(queries)
    summary = BatchSummary(len(query_list), failures_path=Path(f"{out}.failures.txt"))
    start = time.monotonic()
    with h5py.File(features_h5, "r") as features:
        missing = [q.name for q in query_list if q.name not in features]
        if missing:
            raise ValueError(f"{features_h5}: no features for query '{missing[0]}'"
                             f"{f' (and {len(missing) - 1} more)' if len(missing) > 1 else ''}")
        clients: list[LocalizingClient] = []
        local = threading.local()
        lock = threading.Lock()

        def localize(query: Query) -> Outcome:
            if not hasattr(local, "client"):
                local.client = make_client()
                with lock:
                    clients.append(local.client)
            with lock:  # one file handle for every thread: reads take turns
                image = read_hloc_features(features, query.name)
            descriptors = image.descriptors
            if descriptor_dtype is not None:
                descriptors = descriptors.astype(descriptor_dtype)
            try:
                return local.client.localize(image.keypoints, descriptors, query.camera,
                                             query_name=query.name)
            except ServerError as error:
                return error

        executor = ThreadPoolExecutor(max_workers=inflight)
        writer = _SubmissionWriter(Path(out), summary)
        try:
            futures: list[Future] = [executor.submit(localize, q) for q in query_list]
            # In query order, whatever order the replies come in.
            for query, future in zip(query_list, futures):
                writer.write(query, future.result())
        finally:
            writer.close()
            executor.shutdown(wait=True, cancel_futures=True)
            for client in clients:
                client.close()
    summary.seconds = time.monotonic() - start
    return summary
