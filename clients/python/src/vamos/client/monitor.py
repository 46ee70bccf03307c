"""The gRPC client (``vamos.v1.Monitor``), synchronous."""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Optional, Sequence, Union

import grpc

from vamos.v1 import monitor_pb2 as pb
from vamos.v1 import monitor_pb2_grpc as pb_grpc

from . import _convert
from ._types import AlarmEvent, CameraInfo, EpisodeDamaged, FrameScore, SessionError, SessionEvent, SessionSummary
from .episode import Recording, read_episode

Update = Union[FrameScore, SessionEvent, AlarmEvent]
"""What a session yields, in the order the server sent it: a :class:`FrameScore` per
processed frame, a :class:`SessionEvent` (opened, frames dropped, ...), or an
:class:`AlarmEvent` (an alarm started or ended, right after the score of the frame that
caused it). Code that wants only scores tests ``isinstance(u, FrameScore)``."""

_END = object()


def channel_target(server: str) -> tuple[str, bool]:
    """``host:port`` and whether TLS is asked for, from ``host:port``, ``http://...`` or
    ``https://...``."""
    s = server.strip()
    tls = s.startswith("https://")
    for prefix in ("http://", "https://", "grpc://", "grpcs://"):
        if s.startswith(prefix):
            tls = tls or prefix == "grpcs://"
            s = s[len(prefix):]
    return s.rstrip("/"), tls


def _error(e: grpc.RpcError) -> SessionError:
    code = e.code() if hasattr(e, "code") else None
    name = code.name if code is not None else "UNKNOWN"
    details = e.details() if hasattr(e, "details") else str(e)
    return SessionError(name, details or "")


def make_channel(server: str, root_certificates: Optional[bytes], max_message_bytes: int,
                 aio: bool = False) -> Any:
    target, tls = channel_target(server)
    options = [("grpc.max_send_message_length", max_message_bytes),
               ("grpc.max_receive_message_length", max_message_bytes)]
    module: Any = grpc.aio if aio else grpc
    if tls or root_certificates is not None:
        creds = grpc.ssl_channel_credentials(root_certificates=root_certificates)
        return module.secure_channel(target, creds, options=options)
    return module.insecure_channel(target, options=options)


def open_message(profile: str, robot_id: str, session_id: str, task: str,
                 camera: Optional[CameraInfo], anomaly_maps: bool = False, image_rate_hz: float = 0.0) -> Any:
    """The ``StreamRequest`` that opens a session; refuses a negative or non-finite rate."""
    rate = float(image_rate_hz)
    if not (rate >= 0 and rate != float("inf")):
        raise ValueError(f"image_rate_hz must be 0 (not said) or a positive rate, got {image_rate_hz}")
    return pb.StreamRequest(open=pb.OpenSession(
        robot_id=robot_id, profile=profile, task=task, session_id=session_id,
        camera_info=camera.to_proto(pb) if camera is not None else None,
        anomaly_maps=bool(anomaly_maps), image_rate_hz=rate))


def to_update(r: Any) -> Optional[Update]:
    """The typed value of a ``StreamResponse`` (None for a kind this client does not know)."""
    kind = r.WhichOneof("message")
    if kind == "score":
        return FrameScore.from_proto(r.score)
    if kind == "event":
        return SessionEvent.from_proto(r.event)
    if kind == "alarm":
        return AlarmEvent.from_proto(r.alarm)
    return None


class Session:
    """One streamed task execution. Send images, joint states and phase markers in any
    order; iterate over the session for its updates (:data:`Update`: scores, events and
    alarm events, in stream order); :meth:`finish` when done (the server scores what it
    holds, then the iteration ends).

    Not thread-safe for sending from several threads at once; iterating from another
    thread than the sender is fine (and usual)."""

    def __init__(self, stub: Any, metadata: list[tuple[str, str]], open_msg: Any,
                 timeout: Optional[float]) -> None:
        self._stub = stub
        self._metadata = metadata
        self._open = open_msg
        self._timeout = timeout
        self._queue: "queue.Queue[Any]" = queue.Queue()
        self._call: Any = None
        self._responses: Optional[Iterator[Any]] = None
        self._finished = False
        self.opened: Optional[SessionEvent] = None
        self._start()

    def _requests(self, q: "queue.Queue[Any]") -> Iterator[Any]:
        yield self._open
        while True:
            item = q.get()
            if item is _END:
                return
            yield item

    def _start(self) -> None:
        self._queue = queue.Queue()
        call = self._stub.Stream(self._requests(self._queue), metadata=self._metadata,
                                 timeout=self._timeout)
        self._call = call
        self._responses = iter(call)
        try:
            first = next(self._responses)
        except grpc.RpcError as e:
            raise _error(e) from None
        except StopIteration:
            raise SessionError("UNAVAILABLE", "the server closed the stream at open") from None
        update = to_update(first)
        if not isinstance(update, SessionEvent) or update.kind not in ("opened", "resumed"):
            raise SessionError("INTERNAL", f"unexpected first answer {first!r}")
        self.opened = update

    @property
    def session_id(self) -> str:
        """The session's id (the client's, or the one the server gave)."""
        return self.opened.session_id if self.opened else ""

    def resume(self) -> SessionEvent:
        """Re-opens the session after its stream broke: only for a client-chosen
        ``session_id``, within the server's resume window. Buffers and frame counters
        carry on; what was in flight when the stream broke may be lost."""
        if not self._open.open.session_id:
            raise SessionError("FAILED_PRECONDITION", "only a session opened with a session_id can resume")
        self._finished = False
        self._start()
        assert self.opened is not None
        return self.opened

    def send(self, request: Any) -> None:
        """Sends a ready ``vamos.v1.StreamRequest``."""
        if self._finished:
            raise SessionError("FAILED_PRECONDITION", "the session was finished")
        self._queue.put(request)

    def send_image(self, image: Any, stamp_ns: int, encoding: Optional[str] = None,
                   depth: Any = None) -> None:
        """Sends an image: a numpy array (raw pixels) or JPEG/PNG bytes; see
        :func:`vamos.client._convert.image_message`. ``depth``: a depth image registered to
        it (``HxW`` float32 metres or uint16 millimetres; see
        :func:`vamos.client._convert.depth_message`)."""
        self.send(pb.StreamRequest(image=_convert.image_message(image, stamp_ns, encoding, depth)))

    def send_joints(self, names: Sequence[str], positions: Sequence[float], stamp_ns: int,
                    velocities: Sequence[float] = (), efforts: Sequence[float] = ()) -> None:
        """Sends a joint state (radians / metres by name)."""
        self.send(pb.StreamRequest(joints=_convert.joint_message(names, positions, stamp_ns,
                                                                 velocities, efforts)))

    def send_phase(self, phase: str, stamp_ns: int = 0) -> None:
        """Marks the start of a task phase (``"release"``, ``"retract"``, ...)."""
        self.send(pb.StreamRequest(phase=pb.PhaseMarker(phase=phase, stamp_ns=int(stamp_ns))))

    def finish(self) -> None:
        """Ends the request side: the server scores what it holds, then closes."""
        if not self._finished:
            self._finished = True
            self._queue.put(_END)

    def cancel(self) -> None:
        """Drops the stream at once (a resumable session waits for :meth:`resume`)."""
        self._finished = True
        if self._call is not None:
            self._call.cancel()

    def __iter__(self) -> Iterator[Update]:
        assert self._responses is not None
        try:
            for r in self._responses:
                u = to_update(r)
                if u is not None:
                    yield u
        except grpc.RpcError as e:
            if self._call is not None and e.code() == grpc.StatusCode.CANCELLED and self._finished:
                return
            raise _error(e) from None

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc: Any) -> None:
        if exc[0] is None:
            self.finish()
        else:
            self.cancel()


class MonitorClient:
    """A connection to ``vamos serve``'s gRPC port.

    ``server`` is ``host:port`` (or ``http://``/``https://host:port``); ``token`` a robot
    or admin token sent as ``authorization: Bearer``; ``root_certificates`` the PEM of
    the CA for TLS (``https://`` alone uses the system roots)."""

    def __init__(self, server: str = "127.0.0.1:8081", *, token: Optional[str] = None,
                 root_certificates: Optional[bytes] = None, max_message_bytes: int = 64 << 20,
                 timeout: Optional[float] = None) -> None:
        self._channel = make_channel(server, root_certificates, max_message_bytes)
        self._stub = pb_grpc.MonitorStub(self._channel)  # type: ignore[no-untyped-call]  # generated, untyped
        self._metadata = [("authorization", f"Bearer {token}")] if token else []
        self._timeout = timeout

    def wait_ready(self, timeout: float = 30.0) -> None:
        """Blocks until the channel connects (raises :class:`SessionError` on timeout)."""
        try:
            grpc.channel_ready_future(self._channel).result(timeout=timeout)
        except grpc.FutureTimeoutError:
            raise SessionError("UNAVAILABLE", f"no connection within {timeout} s") from None

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "MonitorClient":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def open_session(self, profile: str, *, robot_id: str = "python", session_id: str = "",
                     task: str = "", camera_info: Optional[CameraInfo] = None, anomaly_maps: bool = False,
                     image_rate_hz: float = 0.0) -> Session:
        """Opens a session on ``profile``; raises :class:`SessionError` when the server
        refuses it (``NOT_FOUND`` profile, ``RESOURCE_EXHAUSTED``, ``UNAUTHENTICATED``...).

        ``anomaly_maps``: every score that has one carries the frame's anomaly map
        (:attr:`FrameScore.anomaly_map`, decoded by :meth:`FrameScore.anomaly_map_array`);
        a few hundred bytes per score. ``image_rate_hz``: the rate images will come at (0:
        not said), which the server admits the session by."""
        return Session(self._stub, self._metadata,
                       open_message(profile, robot_id, session_id, task, camera_info, anomaly_maps, image_rate_hz),
                       self._timeout)

    def iter_score_episode(self, path: "str | Path", profile: str, *, name: Optional[str] = None,
                           chunk_bytes: int = 1 << 20) -> Iterator[FrameScore]:
        """Uploads an MCAP episode in chunks (``Monitor.ScoreEpisode``) and yields every
        frame's score. ``name`` (default: the file stem) seeds the predictor as
        ``vamos score`` does. A damaged file raises :class:`EpisodeDamaged` after the
        frames before the damage."""
        path = Path(path)
        episode_name = path.stem if name is None else name

        def chunks() -> Iterator[Any]:
            with open(path, "rb") as fh:
                first = True
                while True:
                    data = fh.read(chunk_bytes)
                    if not data and not first:
                        return
                    yield pb.EpisodeChunk(profile=profile if first else "", data=data,
                                          name=episode_name if first else "")
                    first = False
                    if not data:
                        return

        scores: list[FrameScore] = []
        try:
            for m in self._stub.ScoreEpisode(chunks(), metadata=self._metadata, timeout=self._timeout):
                s = FrameScore.from_proto(m)
                scores.append(s)
                yield s
        except grpc.RpcError as e:
            err = _error(e)
            if err.code == "DATA_LOSS":
                raise EpisodeDamaged(err.details, scores) from None
            raise err from None

    def score_episode(self, path: "str | Path", profile: str, *, name: Optional[str] = None,
                      chunk_bytes: int = 1 << 20) -> list[FrameScore]:
        """:meth:`iter_score_episode`, collected."""
        return list(self.iter_score_episode(path, profile, name=name, chunk_bytes=chunk_bytes))

    def replay(self, episode: "str | Path | Recording", profile: str, *, rate: Optional[float] = 1.0,
               window: int = 4, robot_id: str = "vamos-client", session_id: Optional[str] = None,
               task: str = "", reconnects: int = 3, anomaly_maps: bool = False,
               on_update: Optional[Callable[[Update], None]] = None) -> SessionSummary:
        """Streams a recorded episode as a live robot and collects every answer.

        ``rate``: the recorded pace times this factor (1.0 real time); ``None``: as fast
        as the server scores, with at most ``window`` images unanswered (below the
        server's ``queue_depth``, nothing is dropped). ``session_id`` defaults to the
        episode's file stem, which also makes the scores equal to ``vamos score``'s. When
        the stream breaks, the session is resumed up to ``reconnects`` times. A bag's depth
        images go along when ``episode`` is read with them (``read_episode(path,
        depth_topic=...)``). ``anomaly_maps``: the scores carry their anomaly maps (see
        :meth:`open_session`). ``on_update`` sees every update as it arrives (scores,
        events and alarm events); the summary keeps them by type."""
        if rate is not None and not (rate > 0 and rate != float("inf")):
            raise ValueError(f"rate must be positive, got {rate}")
        if window < 1:
            raise ValueError("window must be at least 1")
        if isinstance(episode, Recording):
            rec, stem = episode, "episode"
        else:
            rec, stem = read_episode(episode), Path(episode).stem
        sid = stem if session_id is None else session_id
        summary = SessionSummary()
        started = time.monotonic()
        lock = threading.Condition()
        pending: list[int] = []  # stamps of images sent and not answered

        def answered(stamp: int) -> None:
            if stamp in pending:
                pending.remove(stamp)

        session = self.open_session(profile, robot_id=robot_id, session_id=sid, task=task,
                                    camera_info=rec.camera, anomaly_maps=anomaly_maps)
        summary.session_id = session.session_id

        def opened(event: Optional[SessionEvent]) -> None:
            if event is not None:
                summary.events.append(event)
                if on_update is not None:
                    on_update(event)

        opened(session.opened)
        failure: list[BaseException] = []
        done = threading.Event()
        broke = threading.Event()

        def reader(s: Session) -> None:
            try:
                for u in s:
                    with lock:
                        if isinstance(u, FrameScore):
                            summary.scores.append(u)
                            answered(u.stamp_ns)
                        elif isinstance(u, AlarmEvent):
                            summary.alarms.append(u)
                        else:
                            summary.events.append(u)
                            if u.kind == "frames_dropped":
                                for _ in range(max(0, u.count - summary.dropped)):
                                    if pending:
                                        pending.pop(0)
                                summary.dropped = max(summary.dropped, u.count)
                            elif u.kind == "message_error":
                                summary.message_errors.append(u.detail)
                                answered(u.stamp_ns)
                        lock.notify_all()
                    if on_update is not None:
                        on_update(u)
            except SessionError as e:
                if e.code == "UNAVAILABLE" and sid:
                    broke.set()
                else:
                    failure.append(e)
            except BaseException as e:  # noqa: B036 - reported to the caller's thread
                failure.append(e)
            finally:
                with lock:
                    lock.notify_all()
                done.set()

        thread = threading.Thread(target=reader, args=(session,), daemon=True)
        thread.start()
        t0 = time.monotonic()
        i = 0
        while i < len(rec.messages):
            offset, msg = rec.messages[i]
            is_image = msg.WhichOneof("message") == "image"
            if rate is not None:
                delay = t0 + offset / 1e9 / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            with lock:
                while is_image and rate is None and len(pending) >= window and not done.is_set():
                    lock.wait(0.5)
            if failure:
                break
            if broke.is_set() or done.is_set():
                if not broke.is_set() or summary.reconnects >= reconnects:
                    break
                # The stream broke: resume the session and go on from this message.
                thread.join()
                broke.clear()
                done.clear()
                time.sleep(min(2.0, 0.1 * 2 ** summary.reconnects))
                summary.reconnects += 1
                with lock:
                    pending.clear()
                try:
                    opened(session.resume())
                except SessionError as e:
                    if summary.reconnects < reconnects and e.code == "UNAVAILABLE":
                        broke.set()
                        done.set()
                        continue
                    failure.append(e)
                    break
                thread = threading.Thread(target=reader, args=(session,), daemon=True)
                thread.start()
                continue
            if is_image:
                with lock:
                    pending.append(msg.image.stamp_ns)
                    summary.images_sent += 1
            session.send(msg)
            i += 1
        session.finish()
        thread.join()
        summary.elapsed_s = time.monotonic() - started
        if failure:
            err = failure[0]
            raise err
        return summary
