"""Every REST administration endpoint as a :class:`Call`: method, path, body and how to
read the answer. :class:`~vamos.client.admin.AdminClient` and
:class:`~vamos.client.admin.AsyncAdminClient` send the same calls, so the two cannot
drift apart. No I/O here."""

from __future__ import annotations

import os
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Generic, Iterable, Optional, Sequence, TypeVar, Union

Json = Any
T = TypeVar("T")


class _Unset:
    def __repr__(self) -> str:
        return "UNSET"


#: "Not given" (``None`` is a value: it clears a threshold, or is JSON null).
UNSET: Any = _Unset()


def _same(body: Any) -> Any:
    return body


@dataclass(frozen=True)
class Call(Generic[T]):
    """One request. The body is at most one of ``json``, ``file`` (streamed from disk),
    ``content`` (bytes or an iterable of bytes with ``length``), or the multipart
    ``files`` + ``fields``. ``post`` turns the parsed JSON (``None`` for an empty answer;
    the bytes with ``raw``) into the method's result. ``hints`` add a sentence to the
    error of a status (what the caller can do about a 403 or 404 of this call)."""

    method: str
    path: str
    post: Callable[[Any], T] = _same
    json: Json = UNSET
    file: Optional[Path] = None
    content: Union[bytes, Iterable[bytes], None] = None
    length: Optional[int] = None
    files: Sequence[tuple[str, Path]] = ()
    fields: Sequence[tuple[str, str]] = ()
    headers: dict[str, str] = field(default_factory=dict)
    raw: bool = False
    hints: dict[int, str] = field(default_factory=dict)


def q(segment: str) -> str:
    """A path segment, percent-encoded (a name may hold ``/`` or spaces)."""
    return urllib.parse.quote(str(segment), safe="")


def raw_call(method: str, path: str, json_body: Json, data: Any, content_type: Optional[str],
             length: Optional[int], accept: Optional[str], raw: bool) -> Call[Any]:
    headers = {}
    if content_type and json_body is UNSET:
        headers["Content-Type"] = content_type
    if accept:
        headers["Accept"] = accept
    return Call(method, path, json=json_body, content=data, length=length, headers=headers, raw=raw)


def _octets(method: str, path: str, file: Path, post: Callable[[Any], T] = _same) -> Call[T]:
    return Call(method, path, post, file=file, headers={"Content-Type": "application/octet-stream"})


def _list(key: str) -> Callable[[Any], list[Json]]:
    return lambda body: list(body[key])


def _id(what: str, value: str) -> str:
    """A non-empty id (an empty one would name another route)."""
    text = str(value).strip()
    if not text:
        raise ValueError(f"{what} must not be empty")
    return text


def healthy() -> Call[bool]:
    return Call("GET", "/healthz", lambda b: isinstance(b, dict) and b.get("status") == "live")


def ready() -> Call[bool]:
    return Call("GET", "/readyz", lambda b: isinstance(b, dict) and b.get("status") == "ready")


def metrics() -> Call[str]:
    return Call("GET", "/metrics", lambda b: bytes(b).decode(), raw=True)


def openapi() -> Call[Json]:
    return Call("GET", "/openapi.json")


def models() -> Call[list[Json]]:
    return Call("GET", "/v1/models", _list("models"))


def model(name: str) -> Call[Json]:
    return Call("GET", f"/v1/models/{q(name)}")


def upload_model(name: str, bundle: Path) -> Call[Json]:
    return _octets("PUT", f"/v1/models/{q(name)}", bundle)


def activate_model(name: str, version: int, reload_sessions: bool) -> Call[Json]:
    return Call("POST", f"/v1/models/{q(name)}/active",
                json={"version": int(version), "reload_sessions": bool(reload_sessions)})


def delete_model(name: str, version: Optional[int]) -> Call[None]:
    path = f"/v1/models/{q(name)}" + (f"/versions/{int(version)}" if version is not None else "")
    return Call("DELETE", path, lambda b: None)


def robots() -> Call[list[Json]]:
    return Call("GET", "/v1/robots", _list("robots"))


def robot(name: str) -> Call[Json]:
    return Call("GET", f"/v1/robots/{q(name)}")


def robot_format(path: Path, format: Optional[str] = None) -> str:
    """``urdf``, ``tar.gz`` or ``zip``: given, or from the file name."""
    fmt = format or ("tar.gz" if path.name.endswith((".tar.gz", ".tgz")) else path.suffix.lstrip("."))
    if fmt not in ("urdf", "tar.gz", "zip"):
        raise ValueError(f"cannot tell the robot format of {path.name}: pass format='urdf', 'tar.gz' or 'zip'")
    return fmt


def upload_robot(name: str, package: Path, format: Optional[str]) -> Call[Json]:
    return _octets("PUT", f"/v1/robots/{q(name)}?format={robot_format(package, format)}", package)


def delete_robot(name: str) -> Call[None]:
    return Call("DELETE", f"/v1/robots/{q(name)}", lambda b: None)


def profiles() -> Call[list[Json]]:
    return Call("GET", "/v1/profiles", _list("profiles"))


def profile(name: str) -> Call[Json]:
    return Call("GET", f"/v1/profiles/{q(name)}")


def put_profile(name: str, spec: Json) -> Call[Json]:
    return Call("PUT", f"/v1/profiles/{q(name)}", json=spec)


def delete_profile(name: str) -> Call[None]:
    return Call("DELETE", f"/v1/profiles/{q(name)}", lambda b: None)


def set_thresholds(name: str, e_c: Optional[float], e_b: Optional[float], alarm: Optional[float]) -> Call[Json]:
    patch = {k: v for k, v in (("e_c", e_c), ("e_b", e_b), ("alarm", alarm)) if v is not UNSET}
    return Call("PATCH", f"/v1/profiles/{q(name)}/thresholds", json=patch)


def calibrate(profile: str, episodes: Sequence[Union[str, "os.PathLike[str]"]],
              holdout: Sequence[Union[str, "os.PathLike[str]"]], alpha: float, upload: bool) -> Call[int]:
    """Local files go as a multipart upload (checked to exist first); server paths as
    JSON."""
    path = f"/v1/profiles/{q(profile)}/calibrate"
    job = lambda b: int(b["job"])  # noqa: E731
    if not upload:
        body = {"episodes": [str(e) for e in episodes], "holdout": [str(h) for h in holdout], "alpha": alpha}
        return Call("POST", path, job, json=body)
    files = [("episodes", Path(e)) for e in episodes] + [("holdout", Path(h)) for h in holdout]
    for _, f in files:
        if not f.is_file():
            raise FileNotFoundError(f)
    return Call("POST", path, job, files=files, fields=[("alpha", repr(float(alpha)))])


def jobs() -> Call[list[Json]]:
    return Call("GET", "/v1/jobs", _list("jobs"))


def job(job_id: int) -> Call[Json]:
    return Call("GET", f"/v1/jobs/{int(job_id)}")


def job_finished(record: Json, failed: Callable[[Json], Exception]) -> bool:
    """True for a succeeded job; raises ``failed(record)`` for a failed or cancelled one."""
    if record["state"] == "succeeded":
        return True
    if record["state"] in ("failed", "cancelled"):
        raise failed(record)
    return False


def cancel_job(job_id: int) -> Call[bool]:
    return Call("DELETE", f"/v1/jobs/{int(job_id)}", lambda b: b is not None)


def store_status() -> Call[Json]:
    return Call("GET", "/v1/store")


def sessions() -> Call[list[Json]]:
    return Call("GET", "/v1/sessions", _list("sessions"))


def reload_session(session_id: str) -> Call[Json]:
    return Call("POST", f"/v1/sessions/{q(session_id)}/reload")


def score_episode(episode: Path, profile: str, name: Optional[str]) -> Call[Json]:
    query = urllib.parse.urlencode({"profile": profile, "name": episode.stem if name is None else name})
    return _octets("POST", f"/v1/episodes:score?{query}", episode)


#: Who may do what with alarms (the server's roles: viewer < robot < admin).
_ALARM_HINTS = {
    401: "alarms need a viewer, robot or admin token",
    404: "a robot token sees only the alarms of its own sessions (or its robots'); admin and viewer "
         "tokens see every alarm",
}


def alarms(session: Optional[str], profile: Optional[str], marked: bool) -> Call[list[Json]]:
    """``GET /v1/alarms``: the recent alarms, newest first, or with ``marked`` the stored
    false alarms, oldest mark first; of one session and/or profile when given."""
    query = {k: v for k, v in (("session", session), ("profile", profile)) if v is not None}
    if marked:
        query["marked"] = "true"
    path = "/v1/alarms" + (f"?{urllib.parse.urlencode(query)}" if query else "")
    return Call("GET", path, _list("alarms"), hints=_ALARM_HINTS)


def alarm(alarm_id: str) -> Call[Json]:
    return Call("GET", f"/v1/alarms/{q(_id('alarm_id', alarm_id))}", hints=_ALARM_HINTS)


def alarm_thumbnail(alarm_id: str) -> Call[bytes]:
    return Call("GET", f"/v1/alarms/{q(_id('alarm_id', alarm_id))}/thumbnail", lambda b: bytes(b), raw=True,
                headers={"Accept": "image/png"}, hints=_ALARM_HINTS)


def mark_false_alarm(alarm_id: str, note: str) -> Call[Json]:
    """``POST /v1/alarms/{id}/false-alarm`` with ``{"note": ...}``."""
    if not isinstance(note, str):
        raise TypeError(f"note must be a string, got {type(note).__name__}")
    return Call("POST", f"/v1/alarms/{q(_id('alarm_id', alarm_id))}/false-alarm", json={"note": note},
                hints={401: "marking a false alarm needs a robot or admin token",
                       403: "marking a false alarm needs a robot or admin token (a viewer's is refused)",
                       404: _ALARM_HINTS[404],
                       409: "an alarm is marked once; the first mark stays"})


def nominal(profile: str) -> Call[list[Json]]:
    """``GET /v1/profiles/{name}/nominal``: the recordings kept by false-alarm marks."""
    return Call("GET", f"/v1/profiles/{q(_id('profile', profile))}/nominal", _list("episodes"))


def recalibrate(profile: str) -> Call[int]:
    """``POST /v1/profiles/{name}/recalibrate``: a job id."""
    return Call("POST", f"/v1/profiles/{q(_id('profile', profile))}/recalibrate", lambda b: int(b["job"]),
                hints={403: "recalibration needs an admin token"})


def apply_job(job_id: int) -> Call[Json]:
    """``POST /v1/jobs/{id}/apply``: the job, its proposal applied."""
    return Call("POST", f"/v1/jobs/{int(job_id)}/apply", hints={403: "applying a proposal needs an admin token"})
