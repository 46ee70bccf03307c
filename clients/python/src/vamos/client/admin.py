"""The REST administration clients (models, robots, profiles, thresholds, calibration
jobs, alarms and false alarms, recalibration, sessions) over httpx: :class:`AdminClient`
(blocking) and :class:`AsyncAdminClient` (asyncio), the same methods with the same
arguments.

Each endpoint is described once, as a :class:`_Call` built by a function of
:mod:`vamos.client._admin_calls`; the two clients only differ in how they send it. Uploads
are streamed from disk with a declared ``Content-Length`` (never held whole in memory),
multipart bodies are httpx's.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import ssl
import tarfile
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any, AsyncIterator, Iterator, Optional, Sequence, TypeVar, Union

import httpx

from . import _admin_calls as calls
from ._admin_calls import UNSET, Call, Json
from ._types import VamosError

T = TypeVar("T")
PathLike = Union[str, "os.PathLike[str]"]
_CHUNK = 1 << 20


class ApiError(VamosError):
    """The server answered with an error status; ``status`` is the HTTP status,
    ``message`` the server's ``{"error": ...}`` text and ``hint`` what the client adds
    for this call (who may call it, ...; empty when nothing)."""

    def __init__(self, status: int, message: str, method: str = "", path: str = "", hint: str = "") -> None:
        text = f"{method} {path}: HTTP {status}: {message}".strip()
        super().__init__(f"{text} ({hint})" if hint else text)
        self.status = status
        self.message = message
        self.hint = hint


class BadRequest(ApiError):
    """400: the request or upload was refused (the message says why)."""


class Unauthorized(ApiError):
    """401: no token, or an unknown one."""


class Forbidden(ApiError):
    """403: the token's role may not do this (a robot token on an admin route, a viewer
    token marking a false alarm)."""


class NotFound(ApiError):
    """404: no such model, robot, profile, session, job or alarm (an alarm of another
    robot's session is unknown to a robot token)."""


class Conflict(ApiError):
    """409: in use or not possible now (a model version a profile needs, a profile file
    of the server's settings, an alarm marked already, a recalibration without a
    calibration or a nominal set...)."""


class PayloadTooLarge(ApiError):
    """413: over the server's upload limit."""


class TooManyRequests(ApiError):
    """429: the server runs its maximum of calibration jobs."""


class ServerError(ApiError):
    """5xx."""


class JobFailed(VamosError):
    """A calibration job ended ``failed`` or ``cancelled``; ``job`` is its record."""

    def __init__(self, job: Json) -> None:
        super().__init__(f"job {job.get('id')} {job.get('state')}: {job.get('error')}")
        self.job = job


_BY_STATUS: dict[int, type[ApiError]] = {400: BadRequest, 401: Unauthorized, 403: Forbidden, 404: NotFound,
                                         409: Conflict, 413: PayloadTooLarge, 429: TooManyRequests}


def _raise(status: int, body: bytes, method: str, path: str, hint: str = "") -> None:
    try:
        message = json.loads(body)["error"]
    except Exception:
        message = body.decode(errors="replace")[:500]
    cls = _BY_STATUS.get(status, ServerError if status >= 500 else ApiError)
    raise cls(status, str(message), method, path, hint)


def _result(call: Call[T], status: int, body: bytes) -> T:
    """The value of a finished call, or the :class:`ApiError` of its status."""
    if status >= 400:
        _raise(status, body, call.method, call.path, call.hints.get(status, ""))
    if call.raw:
        return call.post(body)
    return call.post(None if status == 204 or not body else json.loads(body))


def _file_chunks(path: Path) -> Iterator[bytes]:
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            yield chunk


async def _file_chunks_async(path: Path) -> AsyncIterator[bytes]:
    # Local reads of 1 MiB are short; the event loop is not held for long.
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            yield chunk


@contextlib.contextmanager
def _robot_package(package: PathLike) -> Iterator[Path]:
    """The file to upload for a robot: the path itself, or a folder packed as ``.tar.gz``
    in a temporary folder (removed afterwards)."""
    p = Path(package)
    if not p.is_dir():
        yield p
        return
    with tempfile.TemporaryDirectory() as tmp:
        archive = Path(tmp) / f"{p.name}.tar.gz"
        with tarfile.open(archive, "w:gz") as tar:
            tar.add(p, arcname=p.name)
        yield archive


class _Base:
    def __init__(self, base_url: str, token: Optional[str], timeout: float, ca_file: Optional[str]) -> None:
        if "://" not in base_url:
            base_url = "http://" + base_url
        self.base_url = base_url.rstrip("/")
        self.token = token
        self.timeout = timeout
        self._verify: Union[bool, ssl.SSLContext] = ssl.create_default_context(cafile=ca_file) if ca_file else True

    def _headers(self, call: Call[Any], length: Optional[int]) -> dict[str, str]:
        headers = dict(call.headers)
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        if length is not None:
            headers["Content-Length"] = str(length)
        return headers

    def _transport_error(self, call: Call[Any], e: httpx.TransportError) -> VamosError:
        return VamosError(f"{call.method} {self.base_url}{call.path}: {e}")


class AdminClient(_Base):
    """``vamos serve``'s REST API, blocking. ``base_url`` is the REST address
    (``http://127.0.0.1:8080``); ``token`` an admin token (a robot token may read, score
    and mark its own sessions' false alarms; a viewer token may read alarms); ``ca_file``
    a PEM CA for a TLS server. Usable as a context manager (closes its connection pool)."""

    def __init__(self, base_url: str = "http://127.0.0.1:8080", *, token: Optional[str] = None,
                 timeout: float = 300.0, ca_file: Optional[str] = None) -> None:
        super().__init__(base_url, token, timeout, ca_file)
        self._http = httpx.Client(base_url=self.base_url, timeout=timeout, verify=self._verify)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> "AdminClient":
        return self

    def __exit__(self, et: Optional[type[BaseException]], e: Optional[BaseException],
                 tb: Optional[TracebackType]) -> None:
        self.close()

    def _send(self, call: Call[T]) -> T:
        with contextlib.ExitStack() as stack:
            kwargs: dict[str, Any] = {}
            length = None
            if call.json is not UNSET:
                kwargs["json"] = call.json
            elif call.file is not None:
                kwargs["content"], length = _file_chunks(call.file), call.file.stat().st_size
            elif call.content is not None:
                kwargs["content"], length = call.content, call.length
            if call.files:
                kwargs["files"] = [(f, (p.name, stack.enter_context(open(p, "rb")), "application/octet-stream"))
                                   for f, p in call.files]
                kwargs["data"] = dict(call.fields)
            try:
                r = self._http.request(call.method, call.path, headers=self._headers(call, length), **kwargs)
            except httpx.TransportError as e:
                raise self._transport_error(call, e) from e
        return _result(call, r.status_code, r.content)

    def request(self, method: str, path: str, *, json_body: Json = UNSET, data: Any = None,
                content_type: Optional[str] = None, length: Optional[int] = None,
                accept: Optional[str] = None, raw: bool = False) -> Any:
        """One call; returns the parsed JSON (``None`` for 204), or the bytes with
        ``raw``; raises the :class:`ApiError` subclass of the status. ``data`` is bytes
        or an iterable of bytes (sent with ``length`` as its Content-Length)."""
        return self._send(calls.raw_call(method, path, json_body, data, content_type, length, accept, raw))

    # Health and metrics.
    def healthy(self) -> bool:
        """``GET /healthz`` answers live."""
        try:
            return self._send(calls.healthy())
        except VamosError:
            return False

    def ready(self) -> bool:
        """``GET /readyz`` answers ready."""
        try:
            return self._send(calls.ready())
        except VamosError:
            return False

    def metrics(self) -> str:
        """The Prometheus exposition of ``/metrics``."""
        return self._send(calls.metrics())

    def openapi(self) -> Json:
        """The server's OpenAPI document."""
        return self._send(calls.openapi())

    # Models.
    def models(self) -> list[Json]:
        return self._send(calls.models())

    def model(self, name: str) -> Json:
        return self._send(calls.model(name))

    def upload_model(self, name: str, bundle: PathLike) -> Json:
        """Uploads a model bundle (``.vamos``) as the next version of ``name``; the server
        refuses (:class:`BadRequest`) a bundle that does not load with ONNX Runtime."""
        return self._send(calls.upload_model(name, Path(bundle)))

    def activate_model(self, name: str, version: int, *, reload_sessions: bool = False) -> Json:
        """Makes ``version`` active for new sessions (and, with ``reload_sessions``, for
        running ones, listed in the answer's ``reloaded_sessions``)."""
        return self._send(calls.activate_model(name, version, reload_sessions))

    def delete_model(self, name: str, version: Optional[int] = None) -> None:
        self._send(calls.delete_model(name, version))

    # Robots.
    def robots(self) -> list[Json]:
        return self._send(calls.robots())

    def robot(self, name: str) -> Json:
        return self._send(calls.robot(name))

    def upload_robot(self, name: str, package: PathLike, format: Optional[str] = None) -> Json:
        """Uploads a URDF (``.urdf``) or a robot package (``.tar.gz``, ``.zip``); a folder
        is packed into a ``.tar.gz`` first."""
        with _robot_package(package) as p:
            return self._send(calls.upload_robot(name, p, None if p != Path(package) else format))

    def delete_robot(self, name: str) -> None:
        self._send(calls.delete_robot(name))

    # Profiles and thresholds.
    def profiles(self) -> list[Json]:
        return self._send(calls.profiles())

    def profile(self, name: str) -> Json:
        return self._send(calls.profile(name))

    def put_profile(self, name: str, spec: Json) -> Json:
        """Creates or replaces a stored profile from a ProfileSpec (robot, camera, model,
        pipeline...; see ``/openapi.json``)."""
        return self._send(calls.put_profile(name, spec))

    def delete_profile(self, name: str) -> None:
        self._send(calls.delete_profile(name))

    def set_thresholds(self, name: str, *, e_c: Optional[float] = UNSET,
                       e_b: Optional[float] = UNSET, alarm: Optional[float] = UNSET) -> Json:
        """Overrides thresholds; a value of ``None`` clears that override, an argument not
        given leaves it as it is."""
        return self._send(calls.set_thresholds(name, e_c, e_b, alarm))

    # Calibration jobs.
    def calibrate(self, profile: str, episodes: Sequence[PathLike], holdout: Sequence[PathLike] = (), *,
                  alpha: float = 0.1, upload: bool = True) -> int:
        """Starts a calibration job and returns its id. ``upload``: the episodes are local
        files sent with the request (multipart); otherwise they are paths (files or
        folders) on the server."""
        return self._send(calls.calibrate(profile, episodes, holdout, alpha, upload))

    def jobs(self) -> list[Json]:
        return self._send(calls.jobs())

    def job(self, job_id: int) -> Json:
        return self._send(calls.job(job_id))

    def wait_job(self, job_id: int, *, timeout: float = 3600.0, poll_s: float = 0.5) -> Json:
        """Polls a job until it ends; returns the record of a succeeded job, raises
        :class:`JobFailed` for a failed or cancelled one and :class:`TimeoutError`."""
        deadline = time.monotonic() + timeout
        while True:
            job = self.job(job_id)
            if calls.job_finished(job, JobFailed):
                return job
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} still running after {timeout} s")
            time.sleep(poll_s)

    def cancel_job(self, job_id: int) -> bool:
        """Cancels a running job (True) or removes a finished job's record (False)."""
        return self._send(calls.cancel_job(job_id))

    # Alarms, false alarms and recalibration.
    def alarms(self, *, session: Optional[str] = None, profile: Optional[str] = None,
               marked: bool = False) -> list[Json]:
        """``GET /v1/alarms``: the server's recent alarms, newest first (``marked``: the
        stored false alarms instead, oldest mark first), of one ``session`` and/or
        ``profile`` when given. Each is a dict: ``id``, ``session_id``, ``robot_id``,
        ``profile``, ``model``, ``started_unix_s``, ``start_frame``, ``end_frame``,
        ``end_stamp_ns``, ``frames_flagged``, ``detector``, ``detectors``,
        ``thresholds``, ``start``, ``peak``, and once marked ``false_alarm`` (``by_role``,
        ``marked_unix_s``, ``note``) and ``recording``. Any token may list (viewer,
        robot, admin); a robot token sees only its own sessions' alarms."""
        return self._send(calls.alarms(session, profile, marked))

    def alarm(self, alarm_id: str) -> Json:
        """One alarm (a recent one, else a stored false alarm); :class:`NotFound` for an
        unknown id."""
        return self._send(calls.alarm(alarm_id))

    def alarm_thumbnail(self, alarm_id: str) -> bytes:
        """The frame at the alarm's start, a gray PNG (:meth:`AnomalyMap.from_png
        <vamos.client.AnomalyMap.from_png>` decodes it)."""
        return self._send(calls.alarm_thumbnail(alarm_id))

    def mark_false_alarm(self, alarm_id: str, note: str = "") -> Json:
        """Marks an alarm as a false alarm (``POST /v1/alarms/{id}/false-alarm``) with an
        optional ``note`` (at most 500 characters); returns the alarm with its
        ``false_alarm`` mark. The server stores it, and the session's recording joins the
        profile's nominal set (:meth:`nominal`), which :meth:`recalibrate` learns from.
        Needs a robot token that opened the session (or whose robots it is) or an admin
        token: :class:`Forbidden` for a viewer's, :class:`NotFound` for an alarm the
        token cannot see, :class:`Conflict` when it is marked already."""
        return self._send(calls.mark_false_alarm(alarm_id, note))

    def nominal(self, profile: str) -> list[Json]:
        """``GET /v1/profiles/{name}/nominal``: the profile's nominal set, the kept
        recordings of sessions with an alarm marked as false (``session_id``,
        ``recording``, ``bytes``, ``finished``, ``alarms``, ...), oldest mark first."""
        return self._send(calls.nominal(profile))

    def recalibrate(self, profile: str) -> int:
        """Starts a recalibration of a stored, calibrated profile from its nominal set
        and returns the job's id; follow it with :meth:`wait_job` (its record then has the
        ``proposal``: thresholds now and proposed, each episode's largest score before
        and after) and apply it with :meth:`apply_job`. Admin token. :class:`Conflict`
        when the server cannot start one (a profile file of the server's settings, a
        profile not calibrated, no finished episode in the nominal set),
        :class:`NotFound` for an unknown profile, :class:`TooManyRequests` when the job
        slots are taken."""
        return self._send(calls.recalibrate(profile))

    def apply_job(self, job_id: int) -> Json:
        """Applies a finished recalibration's proposal to its profile; returns the job.
        :class:`Conflict` when it is not a finished recalibration, was applied already, or
        the profile was calibrated again since."""
        return self._send(calls.apply_job(job_id))

    def recalibrate_and_wait(self, profile: str, *, apply: bool = False, timeout: float = 3600.0,
                             poll_s: float = 0.5) -> Json:
        """:meth:`recalibrate`, then :meth:`wait_job` (:class:`JobFailed`,
        :class:`TimeoutError`), then with ``apply`` :meth:`apply_job`; returns the job's
        record (with its ``proposal``)."""
        job = self.recalibrate(profile)
        record = self.wait_job(job, timeout=timeout, poll_s=poll_s)
        return self.apply_job(job) if apply else record

    # The data directory and the fleet.
    def store_status(self) -> Json:
        """``GET /v1/store``: ``{"data_dir", "read_only", "problems", "shared_store"}``;
        ``shared_store`` (None without one) has the replica's ``role``, ``url``,
        ``generation``, ``files``, ``last_sync_unix_s`` and ``last_error``."""
        return self._send(calls.store_status())

    # Sessions and episodes.
    def sessions(self) -> list[Json]:
        return self._send(calls.sessions())

    def reload_session(self, session_id: str) -> Json:
        """Moves a running session to its profile as stored now."""
        return self._send(calls.reload_session(session_id))

    def score_episode(self, episode: PathLike, profile: str, *, name: Optional[str] = None) -> Json:
        """``POST /v1/episodes:score``: ``{"frames": [...], "damage": str|None}``."""
        return self._send(calls.score_episode(Path(episode), profile, name))


class AsyncAdminClient(_Base):
    """:class:`AdminClient` for asyncio: the same methods, as coroutines
    (``await admin.models()``). Close it with ``await admin.aclose()`` or use it as an
    ``async with`` block."""

    def __init__(self, base_url: str = "http://127.0.0.1:8080", *, token: Optional[str] = None,
                 timeout: float = 300.0, ca_file: Optional[str] = None) -> None:
        super().__init__(base_url, token, timeout, ca_file)
        self._http = httpx.AsyncClient(base_url=self.base_url, timeout=timeout, verify=self._verify)

    async def aclose(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> "AsyncAdminClient":
        return self

    async def __aexit__(self, et: Optional[type[BaseException]], e: Optional[BaseException],
                        tb: Optional[TracebackType]) -> None:
        await self.aclose()

    async def _send(self, call: Call[T]) -> T:
        with contextlib.ExitStack() as stack:
            kwargs: dict[str, Any] = {}
            length = None
            if call.json is not UNSET:
                kwargs["json"] = call.json
            elif call.file is not None:
                kwargs["content"], length = _file_chunks_async(call.file), call.file.stat().st_size
            elif call.content is not None:
                if not isinstance(call.content, bytes):
                    raise TypeError("AsyncAdminClient.request takes bytes as data")
                kwargs["content"], length = call.content, call.length
            if call.files:
                kwargs["files"] = [(f, (p.name, stack.enter_context(open(p, "rb")), "application/octet-stream"))
                                   for f, p in call.files]
                kwargs["data"] = dict(call.fields)
            try:
                r = await self._http.request(call.method, call.path, headers=self._headers(call, length), **kwargs)
            except httpx.TransportError as e:
                raise self._transport_error(call, e) from e
        return _result(call, r.status_code, r.content)

    async def request(self, method: str, path: str, *, json_body: Json = UNSET, data: Optional[bytes] = None,
                      content_type: Optional[str] = None, accept: Optional[str] = None, raw: bool = False) -> Any:
        """One call, as :meth:`AdminClient.request` (``data`` as bytes)."""
        return await self._send(calls.raw_call(method, path, json_body, data, content_type,
                                               None if data is None else len(data), accept, raw))

    async def healthy(self) -> bool:
        try:
            return await self._send(calls.healthy())
        except VamosError:
            return False

    async def ready(self) -> bool:
        try:
            return await self._send(calls.ready())
        except VamosError:
            return False

    async def metrics(self) -> str:
        return await self._send(calls.metrics())

    async def openapi(self) -> Json:
        return await self._send(calls.openapi())

    async def models(self) -> list[Json]:
        return await self._send(calls.models())

    async def model(self, name: str) -> Json:
        return await self._send(calls.model(name))

    async def upload_model(self, name: str, bundle: PathLike) -> Json:
        return await self._send(calls.upload_model(name, Path(bundle)))

    async def activate_model(self, name: str, version: int, *, reload_sessions: bool = False) -> Json:
        return await self._send(calls.activate_model(name, version, reload_sessions))

    async def delete_model(self, name: str, version: Optional[int] = None) -> None:
        await self._send(calls.delete_model(name, version))

    async def robots(self) -> list[Json]:
        return await self._send(calls.robots())

    async def robot(self, name: str) -> Json:
        return await self._send(calls.robot(name))

    async def upload_robot(self, name: str, package: PathLike, format: Optional[str] = None) -> Json:
        with _robot_package(package) as p:
            return await self._send(calls.upload_robot(name, p, None if p != Path(package) else format))

    async def delete_robot(self, name: str) -> None:
        await self._send(calls.delete_robot(name))

    async def profiles(self) -> list[Json]:
        return await self._send(calls.profiles())

    async def profile(self, name: str) -> Json:
        return await self._send(calls.profile(name))

    async def put_profile(self, name: str, spec: Json) -> Json:
        return await self._send(calls.put_profile(name, spec))

    async def delete_profile(self, name: str) -> None:
        await self._send(calls.delete_profile(name))

    async def set_thresholds(self, name: str, *, e_c: Optional[float] = UNSET,
                             e_b: Optional[float] = UNSET, alarm: Optional[float] = UNSET) -> Json:
        return await self._send(calls.set_thresholds(name, e_c, e_b, alarm))

    async def calibrate(self, profile: str, episodes: Sequence[PathLike], holdout: Sequence[PathLike] = (), *,
                        alpha: float = 0.1, upload: bool = True) -> int:
        return await self._send(calls.calibrate(profile, episodes, holdout, alpha, upload))

    async def jobs(self) -> list[Json]:
        return await self._send(calls.jobs())

    async def job(self, job_id: int) -> Json:
        return await self._send(calls.job(job_id))

    async def wait_job(self, job_id: int, *, timeout: float = 3600.0, poll_s: float = 0.5) -> Json:
        deadline = time.monotonic() + timeout
        while True:
            job = await self.job(job_id)
            if calls.job_finished(job, JobFailed):
                return job
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} still running after {timeout} s")
            await asyncio.sleep(poll_s)

    async def cancel_job(self, job_id: int) -> bool:
        return await self._send(calls.cancel_job(job_id))

    async def alarms(self, *, session: Optional[str] = None, profile: Optional[str] = None,
                     marked: bool = False) -> list[Json]:
        return await self._send(calls.alarms(session, profile, marked))

    async def alarm(self, alarm_id: str) -> Json:
        return await self._send(calls.alarm(alarm_id))

    async def alarm_thumbnail(self, alarm_id: str) -> bytes:
        return await self._send(calls.alarm_thumbnail(alarm_id))

    async def mark_false_alarm(self, alarm_id: str, note: str = "") -> Json:
        return await self._send(calls.mark_false_alarm(alarm_id, note))

    async def nominal(self, profile: str) -> list[Json]:
        return await self._send(calls.nominal(profile))

    async def recalibrate(self, profile: str) -> int:
        return await self._send(calls.recalibrate(profile))

    async def apply_job(self, job_id: int) -> Json:
        return await self._send(calls.apply_job(job_id))

    async def recalibrate_and_wait(self, profile: str, *, apply: bool = False, timeout: float = 3600.0,
                                   poll_s: float = 0.5) -> Json:
        job = await self.recalibrate(profile)
        record = await self.wait_job(job, timeout=timeout, poll_s=poll_s)
        return await self.apply_job(job) if apply else record

    async def store_status(self) -> Json:
        return await self._send(calls.store_status())

    async def sessions(self) -> list[Json]:
        return await self._send(calls.sessions())

    async def reload_session(self, session_id: str) -> Json:
        return await self._send(calls.reload_session(session_id))

    async def score_episode(self, episode: PathLike, profile: str, *, name: Optional[str] = None) -> Json:
        return await self._send(calls.score_episode(Path(episode), profile, name))


def token_from_env() -> Optional[str]:
    """``VAMOS_TOKEN``, else ``VAMOS_ADMIN_TOKEN``'s first token."""
    t = os.environ.get("VAMOS_TOKEN") or os.environ.get("VAMOS_ADMIN_TOKEN", "").split(",")[0]
    return t.strip() or None
