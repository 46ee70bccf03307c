"""The REST administration clients (blocking and asyncio) on httpx's mock transport: the
requests they send (paths, bodies, streamed uploads with their declared length,
multipart forms) and how answers and errors come back. The same clients against the
real server: test_client_e2e.py and test_packaging.py."""

from __future__ import annotations

import asyncio
import email.parser
import io
import json
from pathlib import Path
from typing import Any, Callable

import pytest

httpx = pytest.importorskip("httpx")

from vamos.client import AdminClient, AsyncAdminClient, Conflict, JobFailed, NotFound, VamosError  # noqa: E402

Handler = Callable[[Any], Any]


class Recorder:
    """Answers every request with ``answer(request)`` and keeps what was sent."""

    def __init__(self, answer: Handler) -> None:
        self.answer = answer
        self.seen: list[tuple[str, str, dict[str, str], bytes]] = []

    def sync(self, request: Any) -> Any:
        body = request.read()
        self.seen.append((request.method, str(request.url), dict(request.headers), body))
        return self.answer(request)

    async def aio(self, request: Any) -> Any:
        body = await request.aread()
        self.seen.append((request.method, str(request.url), dict(request.headers), body))
        return self.answer(request)


def clients(rec: Recorder, token: str = "t0k") -> tuple[AdminClient, AsyncAdminClient]:
    sync = AdminClient("127.0.0.1:9", token=token)
    sync._http = httpx.Client(base_url=sync.base_url, transport=httpx.MockTransport(rec.sync))
    aio = AsyncAdminClient("127.0.0.1:9", token=token)
    aio._http = httpx.AsyncClient(base_url=aio.base_url, transport=httpx.MockTransport(rec.aio))
    return sync, aio


def parse_form(headers: dict[str, str], body: bytes) -> list[tuple[str, Any, bytes]]:
    msg = email.parser.BytesParser().parse(io.BytesIO(
        f"Content-Type: {headers['content-type']}\r\n\r\n".encode() + body))
    return [(p.get_param("name", header="content-disposition"),
             p.get_param("filename", header="content-disposition"), p.get_payload(decode=True))
            for p in msg.get_payload()]


def test_multipart_calibration_uploads_parse_back_with_their_declared_length(tmp_path: Path) -> None:
    a, b = tmp_path / "a.mcap", tmp_path / "second.mcap"
    a.write_bytes(b"\x00\x01" * 100_000)
    b.write_bytes(b"second")
    rec = Recorder(lambda r: httpx.Response(202, json={"job": 7}))
    sync, aio = clients(rec)
    assert sync.calibrate("p 1", [a], [b], alpha=0.2) == 7
    assert asyncio.run(aio.calibrate("p 1", [a], [b], alpha=0.2)) == 7
    for method, url, headers, body in rec.seen:
        assert (method, url) == ("POST", "http://127.0.0.1:9/v1/profiles/p%201/calibrate")
        assert headers["authorization"] == "Bearer t0k"
        assert int(headers["content-length"]) == len(body)
        assert parse_form(headers, body) == [("alpha", None, b"0.2"), ("episodes", "a.mcap", a.read_bytes()),
                                             ("holdout", "second.mcap", b"second")]
    with pytest.raises(FileNotFoundError):
        sync.calibrate("p", [tmp_path / "missing.mcap"])
    # Server-side paths go as JSON.
    assert sync.calibrate("p", ["/data/x.mcap"], upload=False, alpha=0.3) == 7
    assert json.loads(rec.seen[-1][3]) == {"episodes": ["/data/x.mcap"], "holdout": [], "alpha": 0.3}


def test_uploads_stream_the_file_with_its_length(tmp_path: Path) -> None:
    bundle = tmp_path / "m.vamos"
    bundle.write_bytes(bytes(range(256)) * 9000)  # > 2 chunks of 1 MiB
    rec = Recorder(lambda r: httpx.Response(200, json={"name": "m", "version": 3}))
    sync, aio = clients(rec)
    assert sync.upload_model("m", bundle)["version"] == 3
    assert asyncio.run(aio.upload_model("m", bundle))["version"] == 3
    for method, url, headers, body in rec.seen:
        assert (method, url) == ("PUT", "http://127.0.0.1:9/v1/models/m")
        assert headers["content-type"] == "application/octet-stream"
        assert int(headers["content-length"]) == len(body) and body == bundle.read_bytes()
        assert "transfer-encoding" not in headers
    # A robot folder is packed as .tar.gz; a file's format comes from its name.
    pkg = tmp_path / "arm"
    (pkg / "urdf").mkdir(parents=True)
    (pkg / "urdf" / "arm.urdf").write_text("<robot name='arm'/>")
    sync.upload_robot("arm", pkg)
    assert rec.seen[-1][1].endswith("/v1/robots/arm?format=tar.gz") and rec.seen[-1][3][:2] == b"\x1f\x8b"
    asyncio.run(aio.upload_robot("arm", pkg / "urdf" / "arm.urdf"))
    assert rec.seen[-1][1].endswith("/v1/robots/arm?format=urdf")
    with pytest.raises(ValueError, match="cannot tell the robot format"):
        sync.upload_robot("arm", tmp_path / "m.vamos")


def test_answers_and_errors_are_the_same_for_both_clients() -> None:
    def answer(r: Any) -> Any:
        path = r.url.raw_path.decode().split("?")[0]
        if path == "/v1/models":
            return httpx.Response(200, json={"models": [{"name": "a"}]})
        if path == "/v1/models/a%2Fb":
            return httpx.Response(404, json={"error": "no model a/b"})
        if path == "/v1/profiles/p/thresholds":
            return httpx.Response(200, json=json.loads(r.content))
        if path == "/v1/jobs/5":
            return httpx.Response(200, json={"id": 5, "state": "failed", "error": "no frames"})
        if path == "/v1/models/a" and r.method == "DELETE":
            return httpx.Response(409, text="in use, not JSON")
        if path == "/metrics":
            return httpx.Response(200, text="vamos_up 1\n")
        return httpx.Response(204)

    rec = Recorder(answer)
    sync, aio = clients(rec, token="")

    async def run_async() -> list[Any]:
        out: list[Any] = [await aio.models(), await aio.set_thresholds("p", alarm=None, e_c=2.0),
                          await aio.metrics()]
        for coro, exc in ((aio.model("a/b"), NotFound), (aio.wait_job(5), JobFailed),
                          (aio.delete_model("a"), Conflict)):
            with pytest.raises(exc) as info:
                await coro
            out.append(str(info.value))
        await aio.aclose()
        return out

    got_sync: list[Any] = [sync.models(), sync.set_thresholds("p", alarm=None, e_c=2.0), sync.metrics()]
    for call, exc in ((lambda: sync.model("a/b"), NotFound), (lambda: sync.wait_job(5), JobFailed),
                      (lambda: sync.delete_model("a"), Conflict)):
        with pytest.raises(exc) as info:
            call()
        got_sync.append(str(info.value))
    assert got_sync == asyncio.run(run_async())
    assert got_sync[:3] == [[{"name": "a"}], {"e_c": 2.0, "alarm": None}, "vamos_up 1\n"]
    assert got_sync[3] == "GET /v1/models/a%2Fb: HTTP 404: no model a/b"
    assert got_sync[4] == "job 5 failed: no frames"
    assert "HTTP 409: in use, not JSON" in got_sync[5]
    assert all("authorization" not in h for _, _, h, _ in rec.seen)


def test_an_unreachable_server_is_a_vamos_error() -> None:
    def refuse(r: Any) -> Any:
        raise httpx.ConnectError("connection refused", request=r)

    rec = Recorder(refuse)
    sync, aio = clients(rec)
    with pytest.raises(VamosError, match="GET http://127.0.0.1:9/v1/robots: connection refused"):
        sync.robots()
    assert sync.healthy() is False and asyncio.run(aio.ready()) is False
