"""Clients of ``vamos serve``.

- :class:`MonitorClient` (gRPC, synchronous) and :class:`AsyncMonitorClient` (asyncio):
  open a session, push images (numpy arrays or JPEG/PNG bytes) and joint states, iterate
  over scores and events; :meth:`MonitorClient.replay` streams a recorded MCAP episode
  as a live robot (resuming the session when the stream breaks); ``score_episode``
  uploads an episode whole.
- :class:`AdminClient` and :class:`AsyncAdminClient` (REST over httpx, blocking and
  asyncio): models, robots, profiles, thresholds, calibration jobs, sessions, metrics;
  errors are :class:`ApiError` subclasses by status.

Its dependencies (grpcio, protobuf, httpx, mcap, mcap-ros2-support) are the package's
own; numpy is needed only to send numpy arrays as images.
"""

from ._types import (
    CameraInfo,
    EpisodeDamaged,
    FrameScore,
    SessionError,
    SessionEvent,
    SessionSummary,
    VamosError,
)
from .admin import (
    AdminClient,
    ApiError,
    AsyncAdminClient,
    BadRequest,
    Conflict,
    Forbidden,
    JobFailed,
    NotFound,
    PayloadTooLarge,
    ServerError,
    TooManyRequests,
    Unauthorized,
)
from .aio import AsyncMonitorClient, AsyncSession
from .episode import Recording, read_episode
from .monitor import MonitorClient, Session, Update

__all__ = [
    "AdminClient", "ApiError", "AsyncAdminClient", "AsyncMonitorClient", "AsyncSession", "BadRequest", "CameraInfo",
    "Conflict", "EpisodeDamaged", "Forbidden", "FrameScore", "JobFailed", "MonitorClient",
    "NotFound", "PayloadTooLarge", "Recording", "ServerError", "Session", "SessionError",
    "SessionEvent", "SessionSummary", "TooManyRequests", "Unauthorized", "Update", "VamosError",
    "read_episode",
]
