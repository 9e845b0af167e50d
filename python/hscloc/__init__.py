"""hscloc: a Python client of the hscloc localization server (docs/protocol.md).

    import hscloc
    with hscloc.Client("tcp://localhost:5555") as client:
        result = client.localize(keypoints, descriptors, "SIMPLE_RADIAL 1024 768 995 512 384 0.13")
        print(result.status, result.cam_from_world)
"""

from .batch import (BatchSummary, Features, Query, format_pose_line, read_hloc_features,
                    read_query_list)
from .camera import Camera
from .client import Client, ClientOptions
from .errors import HsclocError, ProtocolError, ServerError, ServerTimeoutError
from .requests import LocalizeOptions
from .results import Candidate, Health, LocalizationResult, Pose, ServerInfo, StageTimings

__version__ = "0.1.0"

__all__ = [
    "BatchSummary", "Camera", "Candidate", "Client", "ClientOptions", "Features", "Health",
    "HsclocError", "LocalizationResult", "LocalizeOptions", "Pose", "ProtocolError", "Query",
    "ServerError", "ServerInfo", "ServerTimeoutError", "StageTimings", "format_pose_line",
    "read_hloc_features", "read_query_list",
]
