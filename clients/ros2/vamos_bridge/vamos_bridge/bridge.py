"""The bridge without ROS: a robot's messages in, one vamos session, scores out.

:class:`Bridge` takes messages from the node's callbacks (duck-typed ``sensor_msgs``),
keeps the session (opened at the first image, so the camera info has arrived; joint
states that came before are sent right after; reopened under the same ``session_id``,
which the server resumes, at the next image after the stream broke), and hands every
score to :class:`Outputs` as the fields of a stamped ``vamos_msgs/FrameScore``, every
alarm's start and end as those of a ``vamos_msgs/AlarmEvent`` and, with
``anomaly_maps``, every anomaly map as those of a ``mono8`` ``sensor_msgs/Image`` (the
server is asked for maps only then).
:class:`BridgeState` is its bookkeeping and the diagnostics it implies. With a
``depth_topic``, each image goes with the depth image nearest its stamp within
``max_depth_gap_ms``, waiting for it at most twice that (:mod:`vamos_bridge.depth` has the
rules and bounds; the node calls :meth:`Bridge.release_due` on a timer); without one,
images go at once. The node (:mod:`vamos_bridge.node`) only wires these to rclpy.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Protocol

from vamos.client import AlarmEvent, CameraInfo, FrameScore, SessionError, SessionEvent

from .convert import (FrameIds, alarm_event_fields, anomaly_map_fields, camera_info, depth_image,
                      frame_score_fields, image_request, joints_request, stamp_ns, with_depth)
from .depth import DepthPairer
from .params import Params

# diagnostic_msgs/DiagnosticStatus levels.
OK, WARN, ERROR, STALE = 0, 1, 2, 3


@dataclass
class BridgeState:
    """What the bridge knows about its session, for its outputs."""

    session_id: str = ""
    connected: bool = False
    images_sent: int = 0
    images_with_depth: int = 0
    frames_scored: int = 0
    dropped: int = 0
    refused: int = 0
    reconnects: int = 0
    warming_up: bool = True
    latest: Optional[FrameScore] = None
    last_error: str = ""
    last_image_wall: Optional[float] = None
    last_score_wall: Optional[float] = None
    events: list[str] = field(default_factory=list)

    def on_sent_image(self, now: Optional[float] = None, with_depth: bool = False) -> None:
        self.images_sent += 1
        self.images_with_depth += int(with_depth)
        self.last_image_wall = time.monotonic() if now is None else now

    def on_update(self, u: Any, now: Optional[float] = None) -> Optional[tuple[float, bool]]:
        """Records a score or event; for a score returns ``(score, anomaly)``."""
        if isinstance(u, FrameScore):
            self.frames_scored += 1
            self.latest = u
            self.warming_up = u.warming_up
            self.last_score_wall = time.monotonic() if now is None else now
            return u.score, u.anomaly
        if isinstance(u, SessionEvent):
            if u.kind in ("opened", "resumed", "reloaded"):
                self.session_id = u.session_id
                self.connected = True
            elif u.kind == "frames_dropped":
                self.dropped = max(self.dropped, u.count)
            elif u.kind == "message_error":
                self.refused += 1
                self.last_error = u.detail
            self.events = (self.events + [f"{u.kind}: {u.detail}"])[-10:]
        return None

    def diagnostic(self, now: Optional[float] = None,
                   stale_after_s: float = 5.0) -> tuple[int, str, list[tuple[str, str]]]:
        """``(level, message, key-values)`` of the bridge's DiagnosticStatus."""
        now = time.monotonic() if now is None else now
        values = [
            ("session_id", self.session_id),
            ("images_sent", str(self.images_sent)),
            ("images_with_depth", str(self.images_with_depth)),
            ("frames_scored", str(self.frames_scored)),
            ("dropped", str(self.dropped)),
            ("refused", str(self.refused)),
            ("reconnects", str(self.reconnects)),
        ]
        if self.latest is not None:
            values += [("score", repr(self.latest.score)), ("anomaly", str(self.latest.anomaly)),
                       ("latency_s", f"{self.latest.latency_s:.4f}")]
        if not self.connected:
            return ERROR, f"not connected to vamos{': ' + self.last_error if self.last_error else ''}", values
        if self.last_image_wall is None or now - self.last_image_wall > stale_after_s:
            return STALE, "no images from the camera topic", values
        if self.last_score_wall is None or now - self.last_score_wall > stale_after_s:
            return WARN, "images sent but no scores back", values
        if self.dropped or self.refused:
            return WARN, f"{self.dropped} image(s) dropped, {self.refused} message(s) refused", values
        if self.warming_up:
            return OK, "scoring (flow predictor warming up)", values
        return OK, "scoring", values


class Outputs(Protocol):
    """Where the bridge's results go (the node: publishers and its logger)."""

    def score(self, fields: dict[str, Any]) -> None:
        """One scored frame: the fields of a ``vamos_msgs/FrameScore``."""

    def alarm(self, fields: dict[str, Any]) -> None:
        """An alarm started or ended: the fields of a ``vamos_msgs/AlarmEvent``."""

    def anomaly_map(self, fields: dict[str, Any]) -> None:
        """A frame's anomaly map (with ``anomaly_maps``): the fields of a ``mono8``
        ``sensor_msgs/Image``."""

    def log(self, level: str, text: str) -> None:
        """``level``: ``info`` or ``warning``."""


@dataclass(frozen=True)
class CallbackOutputs:
    """:class:`Outputs` from callables (the node's publishing and logging methods)."""

    on_score: Callable[[dict[str, Any]], None]
    on_log: Callable[[str, str], None]
    on_alarm: Callable[[dict[str, Any]], None]
    on_anomaly_map: Callable[[dict[str, Any]], None]

    def score(self, fields: dict[str, Any]) -> None:
        self.on_score(fields)

    def alarm(self, fields: dict[str, Any]) -> None:
        self.on_alarm(fields)

    def anomaly_map(self, fields: dict[str, Any]) -> None:
        self.on_anomaly_map(fields)

    def log(self, level: str, text: str) -> None:
        self.on_log(level, text)


class Bridge:
    """One robot's session. ``client`` is a :class:`vamos.client.MonitorClient` (or
    anything with its ``open_session``)."""

    #: Images in a row sent without depth (a depth topic set) before a warning.
    WITHOUT_DEPTH_WARNING = 30

    def __init__(self, params: Params, client: Any, outputs: Outputs, early_joints: int = 200,
                 reopen_after_s: float = 1.0) -> None:
        self.params = params
        self.client = client
        self.out = outputs
        self.state = BridgeState()
        self.camera: Optional[CameraInfo] = None
        self.frame_ids = FrameIds()
        self._session: Any = None
        self._early: "collections.deque[Any]" = collections.deque(maxlen=early_joints)
        self._lock = threading.Lock()
        self._readers: list[threading.Thread] = []
        # After a refused open, images are dropped for this long before the next try
        # (a camera at 30 Hz would otherwise try, and log, 30 times a second).
        self._reopen_after_s = reopen_after_s
        self._next_open = 0.0
        # Images waiting for their depth image (None: no depth topic, images go at once).
        # The lock keeps the pairing and the sending in one order whichever thread calls.
        gap_ms = params.max_depth_gap_ms
        self._pairer: Optional[DepthPairer[tuple[Any, str], Any]] = (
            DepthPairer(round(gap_ms * 1e6), 2 * gap_ms / 1000) if params.depth_topic else None)
        self._pair_lock = threading.Lock()
        self._without_depth = 0

    def _ensure_session(self) -> Any:
        with self._lock:
            if self._session is not None:
                return self._session
            if time.monotonic() < self._next_open:
                return None
            p = self.params
            try:
                s = self.client.open_session(p.profile, robot_id=p.robot_id, session_id=p.session_id, task=p.task,
                                             camera_info=self.camera, anomaly_maps=p.anomaly_maps)
            except SessionError as e:
                self.state.connected = False
                self.state.last_error = str(e)
                self._next_open = time.monotonic() + self._reopen_after_s
                self.out.log("warning", f"cannot open the session: {e}; next try in {self._reopen_after_s:g} s")
                return None
            self.state.on_update(s.opened)
            while self._early:
                s.send(self._early.popleft())
            self._session = s
            reader = threading.Thread(target=self._read, args=(s,), name="vamos-bridge-reader", daemon=True)
            self._readers.append(reader)
            reader.start()
            return s

    def _read(self, s: Any) -> None:
        # An alarm event follows the score of the frame that started or ended it: it takes
        # that image's frame id.
        last_frame_id = ""
        try:
            for u in s:
                self.state.on_update(u)
                if isinstance(u, FrameScore):
                    last_frame_id = self.frame_ids.pop(u.stamp_ns)
                    self.out.score(frame_score_fields(u, last_frame_id, self.state.session_id))
                    if self.params.anomaly_maps:
                        self._publish_map(u, last_frame_id)
                elif isinstance(u, AlarmEvent):
                    try:
                        fields = alarm_event_fields(u, last_frame_id, self.params.robot_id)
                    except ValueError as e:
                        self.out.log("warning", f"alarm event not published: {e}")
                        continue
                    self.out.log("info", u.detail)
                    self.out.alarm(fields)
        except SessionError as e:
            self.state.last_error = str(e)
            self.out.log("warning", f"stream ended: {e}; reconnecting at the next image")
        with self._lock:
            if self._session is s:
                self._session = None
                self.state.connected = False
                self.state.reconnects += 1

    def _publish_map(self, score: FrameScore, frame_id: str) -> None:
        try:
            fields = anomaly_map_fields(score, frame_id)
        except ValueError as e:
            self.out.log("warning", f"anomaly map of frame {score.frame} not published: {e}")
            return
        if fields is not None:
            self.out.anomaly_map(fields)

    def on_camera_info(self, msg: Any) -> None:
        """The first usable camera info is kept (sent when the session opens)."""
        if self.camera is None:
            try:
                self.camera = camera_info(msg)
            except ValueError as e:
                self.out.log("warning", f"camera info ignored: {e}")

    def on_image(self, msg: Any) -> None:
        try:
            request = image_request(msg)
        except ValueError as e:
            self.state.refused += 1
            self.out.log("warning", f"image ignored: {e}")
            return
        frame_id = str(getattr(msg.header, "frame_id", ""))
        if self._pairer is None:
            self._send_image(request, frame_id)
            return
        with self._pair_lock:
            self._send_paired(self._pairer.push_image(request.image.stamp_ns, (request, frame_id), time.monotonic()))

    def on_depth(self, msg: Any) -> None:
        """A ``sensor_msgs/Image`` of the depth topic (ignored without one)."""
        if self._pairer is None:
            return
        depth = depth_image(msg)
        with self._pair_lock:
            self._send_paired(self._pairer.push_depth(stamp_ns(msg), depth, time.monotonic()))

    def release_due(self, now: Optional[float] = None) -> None:
        """Sends the images whose wait for a depth image has ended (the node's timer)."""
        if self._pairer is None:
            return
        with self._pair_lock:
            self._send_paired(self._pairer.release_due(time.monotonic() if now is None else now))

    def _send_paired(self, paired: "list[tuple[tuple[Any, str], Any]]") -> None:
        for (request, frame_id), depth in paired:
            self._send_image(with_depth(request, depth), frame_id)

    def _send_image(self, request: Any, frame_id: str) -> None:
        s = self._ensure_session()
        if s is None:
            return
        self.frame_ids.remember(request.image.stamp_ns, frame_id)
        s.send(request)
        has_depth = request.image.HasField("depth")
        self.state.on_sent_image(with_depth=has_depth)
        if self._pairer is None:
            return
        self._without_depth = 0 if has_depth else self._without_depth + 1
        if self._without_depth == self.WITHOUT_DEPTH_WARNING:
            self.out.log("warning", f"{self._without_depth} images in a row sent without a depth image: none on "
                                    f"{self.params.resolved.get('depth_topic', self.params.depth_topic)} within "
                                    f"{self.params.max_depth_gap_ms:g} ms of their stamps; the server uses the "
                                    "profile's assumed depth")

    def on_joint_state(self, msg: Any) -> None:
        request = joints_request(msg)
        with self._lock:
            if self._session is None:
                self._early.append(request)
                return
            s = self._session
        s.send(request)

    def diagnostic(self, now: Optional[float] = None) -> tuple[int, str, list[tuple[str, str]]]:
        """The state's diagnostic, with the robot and the resolved topic names."""
        level, message, values = self.state.diagnostic(now)
        values = [("robot_id", self.params.robot_id), ("profile", self.params.profile), *values,
                  *sorted(self.params.resolved.items())]
        return level, message, values

    def close(self, timeout_s: float = 10.0) -> None:
        """Sends the images still waiting for depth (with what depth there is), finishes
        the session (the server scores what it holds) and waits up to ``timeout_s`` for
        the last scores."""
        if self._pairer is not None:
            with self._pair_lock:
                waiting = self._pairer.drain()
                if waiting and self._session is not None:
                    self._send_paired(waiting)
        with self._lock:
            s, self._session = self._session, None
        if s is not None:
            s.finish()
        deadline = time.monotonic() + timeout_s
        for reader in self._readers:
            reader.join(max(0.0, deadline - time.monotonic()))
