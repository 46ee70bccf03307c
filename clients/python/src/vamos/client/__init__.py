"""Clients of ``vamos serve``.

- :class:`MonitorClient` (gRPC, synchronous) and :class:`AsyncMonitorClient` (asyncio):
  open a session, push images (numpy arrays or JPEG/PNG bytes) and joint states, iterate
  over its updates in stream order (:data:`Update`: :class:`FrameScore`,
  :class:`SessionEvent`, :class:`AlarmEvent`); ``anomaly_maps=True`` gives each score its
  anomaly map (:meth:`FrameScore.anomaly_map_array`); :meth:`MonitorClient.replay`
  streams a recorded MCAP episode as a live robot (resuming the session when the stream
  breaks); ``score_episode`` uploads an episode whole.
- :class:`AdminClient` and :class:`AsyncAdminClient` (REST over httpx, blocking and
  asyncio): models, robots, profiles, thresholds, calibration jobs, alarms, false-alarm
  marks and recalibration, sessions, metrics; errors are :class:`ApiError` subclasses by
  status.

Its dependencies (grpcio, protobuf, httpx, mcap, mcap-ros2-support) are the package's
own; numpy is needed only to send numpy arrays as images.
"""

from ._types import (
    AlarmComponents,
    AlarmEvent,
    AlarmThresholds,
    AnomalyMap,
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
    "AdminClient", "AlarmComponents", "AlarmEvent", "AlarmThresholds", "AnomalyMap", "ApiError", "AsyncAdminClient",
    "AsyncMonitorClient", "AsyncSession", "BadRequest", "CameraInfo",
    "Conflict", "EpisodeDamaged", "Forbidden", "FrameScore", "JobFailed", "MonitorClient",
    "NotFound", "PayloadTooLarge", "Recording", "ServerError", "Session", "SessionError",
    "SessionEvent", "SessionSummary", "TooManyRequests", "Unauthorized", "Update", "VamosError",
    "read_episode",
]
