"""The REST administration client (models, robots, profiles, thresholds, calibration
jobs, sessions), standard library only."""

from __future__ import annotations

import json
import os
import ssl
import time
import urllib.error
import urllib.parse
import urllib.request
import uuid
from pathlib import Path
from typing import Any, Iterable, Iterator, Optional, Sequence, Union

from ._types import VamosError

Json = Any
_UNSET: Any = object()


class ApiError(VamosError):
    """The server answered with an error status; ``status`` is the HTTP status and
    ``message`` the server's ``{"error": ...}`` text."""

    def __init__(self, status: int, message: str, method: str = "", path: str = "") -> None:
        super().__init__(f"{method} {path}: HTTP {status}: {message}".strip())
        self.status = status
        self.message = message


class BadRequest(ApiError):
    """400: the request or upload was refused (the message says why)."""


class Unauthorized(ApiError):
    """401: no token, or an unknown one."""


class Forbidden(ApiError):
    """403: the token's role may not do this (a robot token on an admin route)."""


class NotFound(ApiError):
    """404: no such model, robot, profile, session or job."""


class Conflict(ApiError):
    """409: in use (a model version a profile needs, a profile file...)."""


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


_BY_STATUS = {400: BadRequest, 401: Unauthorized, 403: Forbidden, 404: NotFound, 409: Conflict,
              413: PayloadTooLarge, 429: TooManyRequests}


def _raise(status: int, body: bytes, method: str, path: str) -> None:
    try:
        message = json.loads(body)["error"]
    except Exception:
        message = body.decode(errors="replace")[:500]
    cls = _BY_STATUS.get(status, ServerError if status >= 500 else ApiError)
    raise cls(status, str(message), method, path)


class _Multipart:
    """A ``multipart/form-data`` body streamed from files (never held whole)."""

    def __init__(self, files: Sequence[tuple[str, Path]], fields: Sequence[tuple[str, str]]) -> None:
        self.boundary = f"vamos-{uuid.uuid4().hex}"
        self._parts: list[Union[bytes, Path]] = []
        for name, value in fields:
            self._parts.append(
                f'--{self.boundary}\r\nContent-Disposition: form-data; name="{name}"\r\n\r\n{value}\r\n'
                .encode())
        for name, path in files:
            filename = path.name.replace('"', "_").replace("\r", "_").replace("\n", "_")
            self._parts.append(
                (f'--{self.boundary}\r\nContent-Disposition: form-data; name="{name}"; '
                 f'filename="{filename}"\r\nContent-Type: application/octet-stream\r\n\r\n').encode())
            self._parts.append(path)
            self._parts.append(b"\r\n")
        self._parts.append(f"--{self.boundary}--\r\n".encode())

    @property
    def content_type(self) -> str:
        return f"multipart/form-data; boundary={self.boundary}"

    def __len__(self) -> int:
        return sum(p.stat().st_size if isinstance(p, Path) else len(p) for p in self._parts)

    def __iter__(self) -> Iterator[bytes]:
        for p in self._parts:
            if isinstance(p, Path):
                with open(p, "rb") as fh:
                    while chunk := fh.read(1 << 20):
                        yield chunk
            else:
                yield p


def _file_chunks(path: Path) -> Iterable[bytes]:
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            yield chunk


class AdminClient:
    """``vamos serve``'s REST API. ``base_url`` is the REST address
    (``http://127.0.0.1:8080``); ``token`` an admin token (a robot token may read and
    score only); ``ca_file`` a PEM CA for a TLS server."""

    def __init__(self, base_url: str = "http://127.0.0.1:8080", *, token: Optional[str] = None,
                 timeout: float = 300.0, ca_file: Optional[str] = None) -> None:
        if "://" not in base_url:
            base_url = "http://" + base_url
        self.base_url = base_url.rstrip("/")
        self.token = token
        self.timeout = timeout
        self._context = ssl.create_default_context(cafile=ca_file) if ca_file else None

    def request(self, method: str, path: str, *, json_body: Json = _UNSET,
                data: Any = None, content_type: Optional[str] = None,
                length: Optional[int] = None, accept: Optional[str] = None,
                raw: bool = False) -> Any:
        """One call; returns the parsed JSON (``None`` for 204), or the bytes with
        ``raw``; raises the :class:`ApiError` subclass of the status."""
        headers: dict[str, str] = {}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        if json_body is not _UNSET:
            data = json.dumps(json_body).encode()
            content_type = "application/json"
        if content_type:
            headers["Content-Type"] = content_type
        if accept:
            headers["Accept"] = accept
        if length is not None:
            headers["Content-Length"] = str(length)
        req = urllib.request.Request(self.base_url + path, data=data, method=method, headers=headers)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout, context=self._context) as resp:
                body = resp.read()
                if raw:
                    return body
                if resp.status == 204 or not body:
                    return None
                return json.loads(body)
        except urllib.error.HTTPError as e:
            _raise(e.code, e.read(), method, path)
        except urllib.error.URLError as e:
            raise VamosError(f"{method} {self.base_url}{path}: {e.reason}") from e

    def _upload(self, method: str, path: str, file: "str | Path", content_type: str) -> Json:
        p = Path(file)
        return self.request(method, path, data=_file_chunks(p), content_type=content_type,
                            length=p.stat().st_size)

    # Health and metrics.
    def healthy(self) -> bool:
        """``GET /healthz``."""
        try:
            return self.request("GET", "/healthz").get("status") == "live"
        except VamosError:
            return False

    def ready(self) -> bool:
        """``GET /readyz``."""
        try:
            return self.request("GET", "/readyz").get("status") == "ready"
        except VamosError:
            return False

    def metrics(self) -> str:
        """The Prometheus exposition of ``/metrics``."""
        return bytes(self.request("GET", "/metrics", raw=True)).decode()

    def openapi(self) -> Json:
        return self.request("GET", "/openapi.json")

    # Models.
    def models(self) -> list[Json]:
        return list(self.request("GET", "/v1/models")["models"])

    def model(self, name: str) -> Json:
        return self.request("GET", f"/v1/models/{_q(name)}")

    def upload_model(self, name: str, bundle: "str | Path") -> Json:
        """Uploads a model bundle (``.vamos``) as the next version of ``name``; the server
        refuses (:class:`BadRequest`) a bundle that does not load with ONNX Runtime."""
        return self._upload("PUT", f"/v1/models/{_q(name)}", bundle, "application/octet-stream")

    def activate_model(self, name: str, version: int, *, reload_sessions: bool = False) -> Json:
        """Makes ``version`` active for new sessions (and, with ``reload_sessions``, for
        running ones, listed in the answer's ``reloaded_sessions``)."""
        return self.request("POST", f"/v1/models/{_q(name)}/active",
                            json_body={"version": int(version), "reload_sessions": reload_sessions})

    def delete_model(self, name: str, version: Optional[int] = None) -> None:
        path = f"/v1/models/{_q(name)}" + (f"/versions/{int(version)}" if version is not None else "")
        self.request("DELETE", path)

    # Robots.
    def robots(self) -> list[Json]:
        return list(self.request("GET", "/v1/robots")["robots"])

    def robot(self, name: str) -> Json:
        return self.request("GET", f"/v1/robots/{_q(name)}")

    def upload_robot(self, name: str, package: "str | Path", format: Optional[str] = None) -> Json:
        """Uploads a URDF (``.urdf``) or a robot package (``.tar.gz``, ``.zip``); a folder
        is packed into a ``.tar.gz`` first."""
        p = Path(package)
        if p.is_dir():
            import tarfile
            import tempfile

            with tempfile.TemporaryDirectory() as tmp:
                archive = Path(tmp) / f"{p.name}.tar.gz"
                with tarfile.open(archive, "w:gz") as tar:
                    tar.add(p, arcname=p.name)
                return self.upload_robot(name, archive, "tar.gz")
        fmt = format or ("tar.gz" if p.name.endswith((".tar.gz", ".tgz")) else p.suffix.lstrip("."))
        if fmt not in ("urdf", "tar.gz", "zip"):
            raise ValueError(f"cannot tell the robot format of {p.name}: pass format='urdf', 'tar.gz' or 'zip'")
        return self._upload("PUT", f"/v1/robots/{_q(name)}?format={fmt}", p, "application/octet-stream")

    def delete_robot(self, name: str) -> None:
        self.request("DELETE", f"/v1/robots/{_q(name)}")

    # Profiles and thresholds.
    def profiles(self) -> list[Json]:
        return list(self.request("GET", "/v1/profiles")["profiles"])

    def profile(self, name: str) -> Json:
        return self.request("GET", f"/v1/profiles/{_q(name)}")

    def put_profile(self, name: str, spec: Json) -> Json:
        """Creates or replaces a stored profile from a ProfileSpec (robot, camera, model,
        pipeline...; see ``/openapi.json``)."""
        return self.request("PUT", f"/v1/profiles/{_q(name)}", json_body=spec)

    def delete_profile(self, name: str) -> None:
        self.request("DELETE", f"/v1/profiles/{_q(name)}")

    def set_thresholds(self, name: str, *, e_c: Optional[float] = _UNSET,
                       e_b: Optional[float] = _UNSET, alarm: Optional[float] = _UNSET) -> Json:
        """Overrides thresholds; a value of ``None`` clears that override, an argument not
        given leaves it as it is."""
        patch = {k: v for k, v in (("e_c", e_c), ("e_b", e_b), ("alarm", alarm)) if v is not _UNSET}
        return self.request("PATCH", f"/v1/profiles/{_q(name)}/thresholds", json_body=patch)

    # Calibration jobs.
    def calibrate(self, profile: str, episodes: Sequence["str | Path"],
                  holdout: Sequence["str | Path"] = (), *, alpha: float = 0.1,
                  upload: bool = True) -> int:
        """Starts a calibration job and returns its id. ``upload``: the episodes are local
        files sent with the request; otherwise they are paths (files or folders) on the
        server."""
        path = f"/v1/profiles/{_q(profile)}/calibrate"
        if not upload:
            body = {"episodes": [str(e) for e in episodes], "holdout": [str(h) for h in holdout],
                    "alpha": alpha}
            return int(self.request("POST", path, json_body=body)["job"])
        files = [("episodes", Path(e)) for e in episodes] + [("holdout", Path(h)) for h in holdout]
        for _, f in files:
            if not f.is_file():
                raise FileNotFoundError(f)
        form = _Multipart(files, [("alpha", repr(float(alpha)))])
        return int(self.request("POST", path, data=iter(form), content_type=form.content_type,
                                length=len(form))["job"])

    def jobs(self) -> list[Json]:
        return list(self.request("GET", "/v1/jobs")["jobs"])

    def job(self, job_id: int) -> Json:
        return self.request("GET", f"/v1/jobs/{int(job_id)}")

    def wait_job(self, job_id: int, *, timeout: float = 3600.0, poll_s: float = 0.5) -> Json:
        """Polls a job until it ends; returns the record of a succeeded job, raises
        :class:`JobFailed` for a failed or cancelled one and :class:`TimeoutError`."""
        deadline = time.monotonic() + timeout
        while True:
            job = self.job(job_id)
            if job["state"] == "succeeded":
                return job
            if job["state"] in ("failed", "cancelled"):
                raise JobFailed(job)
            if time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} still running after {timeout} s")
            time.sleep(poll_s)

    def cancel_job(self, job_id: int) -> bool:
        """Cancels a running job (True) or removes a finished job's record (False)."""
        return self.request("DELETE", f"/v1/jobs/{int(job_id)}") is not None

    # The data directory and the fleet.
    def store_status(self) -> Json:
        """``GET /v1/store``: ``{"data_dir", "read_only", "problems", "shared_store"}``;
        ``shared_store`` (None without one) has the replica's ``role``, ``url``,
        ``generation``, ``files``, ``last_sync_unix_s`` and ``last_error``."""
        return self.request("GET", "/v1/store")

    # Sessions and episodes.
    def sessions(self) -> list[Json]:
        return list(self.request("GET", "/v1/sessions")["sessions"])

    def reload_session(self, session_id: str) -> Json:
        """Moves a running session to its profile as stored now."""
        return self.request("POST", f"/v1/sessions/{_q(session_id)}/reload")

    def score_episode(self, episode: "str | Path", profile: str, *, name: Optional[str] = None) -> Json:
        """``POST /v1/episodes:score``: ``{"frames": [...], "damage": str|None}``."""
        p = Path(episode)
        query = urllib.parse.urlencode({"profile": profile, "name": p.stem if name is None else name})
        return self._upload("POST", f"/v1/episodes:score?{query}", p, "application/octet-stream")


def _q(segment: str) -> str:
    return urllib.parse.quote(str(segment), safe="")


def token_from_env() -> Optional[str]:
    """``VAMOS_TOKEN``, else ``VAMOS_ADMIN_TOKEN``'s first token."""
    t = os.environ.get("VAMOS_TOKEN") or os.environ.get("VAMOS_ADMIN_TOKEN", "").split(",")[0]
    return t.strip() or None
