"""The gRPC client (``vamos.v1.Monitor``) for asyncio."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any, AsyncIterator, Optional, Sequence

import grpc

from vamos.v1 import monitor_pb2 as pb
from vamos.v1 import monitor_pb2_grpc as pb_grpc

from . import _convert
from ._types import CameraInfo, EpisodeDamaged, FrameScore, SessionError, SessionEvent
from .monitor import Update, _error, make_channel, open_message, to_update

_END = object()


class AsyncSession:
    """One streamed task execution (asyncio): ``await send_*``, ``async for`` over the
    updates (:data:`vamos.client.Update`: scores, events and alarm events, in stream
    order), ``await finish()`` when done."""

    def __init__(self, call: Any, queue: "asyncio.Queue[Any]", opened: SessionEvent) -> None:
        self._call = call
        self._queue = queue
        self._finished = False
        self.opened = opened

    @property
    def session_id(self) -> str:
        return self.opened.session_id

    async def send(self, request: Any) -> None:
        if self._finished:
            raise SessionError("FAILED_PRECONDITION", "the session was finished")
        await self._queue.put(request)

    async def send_image(self, image: Any, stamp_ns: int, encoding: Optional[str] = None,
                         depth: Any = None) -> None:
        await self.send(pb.StreamRequest(image=_convert.image_message(image, stamp_ns, encoding, depth)))

    async def send_joints(self, names: Sequence[str], positions: Sequence[float], stamp_ns: int,
                          velocities: Sequence[float] = (), efforts: Sequence[float] = ()) -> None:
        await self.send(pb.StreamRequest(joints=_convert.joint_message(
            names, positions, stamp_ns, velocities, efforts)))

    async def send_phase(self, phase: str, stamp_ns: int = 0) -> None:
        await self.send(pb.StreamRequest(phase=pb.PhaseMarker(phase=phase, stamp_ns=int(stamp_ns))))

    async def finish(self) -> None:
        if not self._finished:
            self._finished = True
            await self._queue.put(_END)

    def cancel(self) -> None:
        self._finished = True
        self._call.cancel()

    async def __aiter__(self) -> AsyncIterator[Update]:
        # `read()` throughout: grpc.aio forbids mixing it with `async for` on one call,
        # and the opening answer was read with it.
        try:
            while True:
                r = await self._call.read()
                if r is grpc.aio.EOF:
                    return
                u = to_update(r)
                if u is not None:
                    yield u
        except grpc.RpcError as e:
            if e.code() == grpc.StatusCode.CANCELLED and self._finished:
                return
            raise _error(e) from None


class AsyncMonitorClient:
    """:class:`vamos.client.MonitorClient` for asyncio (``grpc.aio``); use it as an
    ``async with`` context."""

    def __init__(self, server: str = "127.0.0.1:8081", *, token: Optional[str] = None,
                 root_certificates: Optional[bytes] = None, max_message_bytes: int = 64 << 20,
                 timeout: Optional[float] = None) -> None:
        self._channel = make_channel(server, root_certificates, max_message_bytes, aio=True)
        self._stub = pb_grpc.MonitorStub(self._channel)  # type: ignore[no-untyped-call]  # generated, untyped
        self._metadata = [("authorization", f"Bearer {token}")] if token else []
        self._timeout = timeout

    async def close(self) -> None:
        await self._channel.close()

    async def __aenter__(self) -> "AsyncMonitorClient":
        return self

    async def __aexit__(self, *exc: Any) -> None:
        await self.close()

    async def open_session(self, profile: str, *, robot_id: str = "python", session_id: str = "",
                           task: str = "", camera_info: Optional[CameraInfo] = None, anomaly_maps: bool = False,
                           image_rate_hz: float = 0.0) -> AsyncSession:
        """:meth:`vamos.client.MonitorClient.open_session` (the same arguments, among them
        ``anomaly_maps``); raises :class:`SessionError` when the server refuses it."""
        queue: "asyncio.Queue[Any]" = asyncio.Queue()
        first_msg = open_message(profile, robot_id, session_id, task, camera_info, anomaly_maps, image_rate_hz)

        async def requests() -> AsyncIterator[Any]:
            yield first_msg
            while True:
                item = await queue.get()
                if item is _END:
                    return
                yield item

        call = self._stub.Stream(requests(), metadata=self._metadata, timeout=self._timeout)
        try:
            first = await call.read()
        except grpc.RpcError as e:
            raise _error(e) from None
        if first is grpc.aio.EOF:
            code = await call.code()
            raise SessionError(code.name, await call.details() or "the server closed the stream")
        opened = to_update(first)
        if not isinstance(opened, SessionEvent):
            raise SessionError("INTERNAL", f"unexpected first answer {first!r}")
        return AsyncSession(call, queue, opened)

    async def score_episode(self, path: "str | Path", profile: str, *, name: Optional[str] = None,
                            chunk_bytes: int = 1 << 20) -> list[FrameScore]:
        """Uploads an MCAP episode (``Monitor.ScoreEpisode``) and returns every frame's
        score; :class:`EpisodeDamaged` when the file is cut short."""
        path = Path(path)
        data = await asyncio.to_thread(path.read_bytes)
        episode_name = path.stem if name is None else name
        chunks = [pb.EpisodeChunk(profile=profile if i == 0 else "", name=episode_name if i == 0 else "",
                                  data=data[o:o + chunk_bytes])
                  for i, o in enumerate(range(0, max(len(data), 1), chunk_bytes))]
        scores: list[FrameScore] = []
        try:
            async for m in self._stub.ScoreEpisode(iter(chunks), metadata=self._metadata,
                                                   timeout=self._timeout):
                scores.append(FrameScore.from_proto(m))
        except grpc.RpcError as e:
            err = _error(e)
            if err.code == "DATA_LOSS":
                raise EpisodeDamaged(err.details, scores) from None
            raise err from None
        return scores
