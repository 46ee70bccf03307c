"""Alarm events, anomaly maps and the alarm / false-alarm / recalibration calls of the
client, without a server: parsing of the wire messages, the PNG reader, the requests the
REST clients send and the errors they raise. Against the real server:
test_alarms_e2e.py."""

from __future__ import annotations

import asyncio
import json
import random
import struct
import zlib
from typing import Any

import pytest

pytest.importorskip("grpc")
httpx = pytest.importorskip("httpx")

from vamos.client import (  # noqa: E402
    AdminClient,
    AlarmComponents,
    AlarmEvent,
    AnomalyMap,
    AsyncAdminClient,
    Conflict,
    Forbidden,
    FrameScore,
    NotFound,
    SessionEvent,
)
from vamos.client import _png  # noqa: E402
from vamos.client.cli import build_parser, main  # noqa: E402
from vamos.client.monitor import open_message, to_update  # noqa: E402
from vamos.v1 import monitor_pb2 as pb  # noqa: E402


# --- alarm events from the wire -------------------------------------------------------

def _alarm(**kw: Any) -> Any:
    fields: dict[str, Any] = dict(
        edge=pb.AlarmEvent.EDGE_STARTED, alarm_id="al-1-1", session_id="s-1", detector=pb.DETECTOR_SCENE,
        detectors=[pb.DETECTOR_SCENE, pb.DETECTOR_BODY], start_frame=3, frames_flagged=3,
        alarm_threshold=0.0, e_c_threshold=2.5, e_r_threshold=1.0,
        start=pb.AlarmComponents(stamp_ns=300, score=0.25, e_c=0.0, e_r=0.25),
        peak=pb.AlarmComponents(stamp_ns=500, score=4.0, e_b=1.5, e_k=0.5))
    fields.update(kw)
    return pb.AlarmEvent(**fields)


def test_an_alarm_start_from_the_wire() -> None:
    a = AlarmEvent.from_proto(_alarm())
    assert (a.edge, a.started, a.ended, a.alarm_id, a.session_id) == ("started", True, False, "al-1-1", "s-1")
    assert (a.detector, a.detectors, a.start_frame, a.frames_flagged) == ("scene", ("scene", "body"), 3, 3)
    assert (a.end_frame, a.end_stamp_ns) == (None, None)
    # Presence is kept: a threshold of 0 is a value, an absent one is None.
    t = a.thresholds
    assert (t.alarm, t.e_c, t.e_b, t.e_o, t.e_r, t.e_k) == (0.0, 2.5, None, None, 1.0, None)
    assert a.start == AlarmComponents(stamp_ns=300, score=0.25, e_c=0.0, e_r=0.25)
    assert a.peak == AlarmComponents(stamp_ns=500, score=4.0, e_b=1.5, e_k=0.5)
    # What it shares with SessionEvent, for code that logs every update that is not a score.
    assert (a.kind, a.stamp_ns) == ("alarm_started", 300)
    assert a.detail == "alarm al-1-1 started at frame 3 (scene)"
    d = a.to_dict()
    assert json.loads(json.dumps(d)) == d
    assert d["thresholds"] == {"alarm": 0.0, "e_c": 2.5, "e_b": None, "e_o": None, "e_r": 1.0, "e_k": None}
    assert d["detectors"] == ["scene", "body"] and d["peak"]["e_b"] == 1.5


def test_an_alarm_end_and_unknown_values() -> None:
    a = AlarmEvent.from_proto(_alarm(edge=pb.AlarmEvent.EDGE_ENDED, end_frame=0, end_stamp_ns=900,
                                     frames_flagged=7))
    assert (a.ended, a.end_frame, a.end_stamp_ns, a.kind, a.stamp_ns) == (True, 0, 900, "alarm_ended", 900)
    assert a.detail == "alarm al-1-1 ended at frame 0 after 7 flagged frame(s) (scene, body)"
    # A newer server's values this client does not know are named, not dropped.
    b = AlarmEvent.from_proto(pb.AlarmEvent(edge=7, alarm_id="x", detector=42, detectors=[42]))
    assert (b.edge, b.detector, b.detectors, b.kind) == ("unknown", None, ("unknown",), "alarm_unknown")
    assert b.start == AlarmComponents() and b.thresholds.alarm is None


def test_the_stream_yields_scores_events_and_alarms_by_type() -> None:
    updates = [to_update(r) for r in (
        pb.StreamResponse(event=pb.SessionEvent(kind=pb.SessionEvent.KIND_OPENED, session_id="s-1")),
        pb.StreamResponse(score=pb.FrameScore(frame=3, stamp_ns=300, anomaly=True)),
        pb.StreamResponse(alarm=_alarm()),
        pb.StreamResponse())]
    assert [type(u) for u in updates] == [SessionEvent, FrameScore, AlarmEvent, type(None)]


def test_scores_carry_their_anomaly_map_and_lost_frames() -> None:
    png = _encode_png(3, 2, bytes([0, 10, 255, 4, 5, 6]), filters=[0, 1])
    s = FrameScore.from_proto(pb.FrameScore(frame=1, frames_lost=2, anomaly_map=png))
    assert s.frames_lost == 2 and s.anomaly_map == png
    m = s.anomaly_map_image()
    assert m is not None
    assert (m.width, m.height, m.shape, m.pixels) == (3, 2, (2, 3), bytes([0, 10, 255, 4, 5, 6]))
    assert (m.at(2, 0), m.at(0, 1)) == (255, 4)
    with pytest.raises(IndexError):
        m.at(3, 0)
    assert "anomaly_map" not in s.to_dict() and s.to_dict()["frames_lost"] == 2
    # No map: None, not an empty image.
    plain = FrameScore.from_proto(pb.FrameScore(frame=1))
    assert plain.anomaly_map is None and plain.anomaly_map_image() is None and plain.anomaly_map_array() is None


def test_anomaly_maps_as_numpy_arrays() -> None:
    np = pytest.importorskip("numpy")
    pixels = bytes(range(12))
    s = FrameScore.from_proto(pb.FrameScore(anomaly_map=_encode_png(4, 3, pixels, filters=[2, 3, 4])))
    a = s.anomaly_map_array()
    assert a.dtype == np.uint8 and a.shape == (3, 4)
    assert a.tolist() == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]


def test_sessions_are_opened_with_anomaly_maps_and_a_rate() -> None:
    m = open_message("p", "r", "s", "t", None, anomaly_maps=True, image_rate_hz=15)
    assert m.open.anomaly_maps is True and m.open.image_rate_hz == 15.0 and m.open.profile == "p"
    assert open_message("p", "r", "s", "t", None).open.anomaly_maps is False
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="image_rate_hz"):
            open_message("p", "r", "s", "t", None, image_rate_hz=bad)


# --- the PNG reader -------------------------------------------------------------------

def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _paeth(a: int, b: int, c: int) -> int:
    p = a + b - c
    pa, pb_, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb_ and pa <= pc else b if pb_ <= pc else c


def _encode_png(width: int, height: int, pixels: bytes, filters: list[int], depth: int = 8, colour: int = 0,
                interlace: int = 0) -> bytes:
    """An 8-bit gray PNG with the given row filters (cycled), written by hand: the
    reader is checked against the specification, not against another decoder."""
    raw = bytearray()
    prior = [0] * width
    for y in range(height):
        row = list(pixels[y * width:(y + 1) * width])
        f = filters[y % len(filters)]
        out = []
        for x in range(width):
            a = row[x - 1] if x else 0
            b, c = prior[x], prior[x - 1] if x else 0
            pred = [0, a, b, (a + b) // 2, _paeth(a, b, c)][f]
            out.append((row[x] - pred) & 0xFF)
        raw += bytes([f]) + bytes(out)
        prior = row
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, interlace)
    return (_png.SIGNATURE + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(bytes(raw)))
            + _chunk(b"IEND", b""))


@pytest.mark.parametrize("f", [0, 1, 2, 3, 4])
def test_the_png_reader_undoes_every_row_filter(f: int) -> None:
    rng = random.Random(f)
    width, height = 37, 11
    pixels = bytes(rng.randrange(256) for _ in range(width * height))
    assert _png.decode_gray8(_encode_png(width, height, pixels, [f])) == (width, height, pixels)
    # Mixed filters, row by row, as an adaptive encoder writes them.
    mixed = _encode_png(width, height, pixels, [f, (f + 1) % 5, (f + 3) % 5])
    assert AnomalyMap.from_png(mixed) == AnomalyMap(width, height, pixels)


def test_the_png_reader_refuses_what_it_cannot_read() -> None:
    good = _encode_png(2, 2, bytes(4), [0])
    cases = {
        b"GIF89a" + good[6:]: "not a PNG",
        good[:-20]: "truncated",
        good[:29] + bytes([good[29] ^ 0xFF]) + good[30:]: "bad CRC",
        _encode_png(2, 2, bytes(12), [0], colour=2): "not 8-bit grayscale",
        _encode_png(2, 2, bytes(4), [0], depth=16): "not 8-bit grayscale",
        _encode_png(2, 2, bytes(4), [0], interlace=1): "interlaced",
    }
    for data, why in cases.items():
        with pytest.raises(ValueError, match=why):
            _png.decode_gray8(data)
    bad_filter = bytearray(zlib.decompress(good[41:41 + struct.unpack(">I", good[33:37])[0]]))
    assert len(bad_filter) == 6
    bad_filter[3] = 9
    idat = zlib.compress(bytes(bad_filter))
    with pytest.raises(ValueError, match="unknown filter type 9"):
        _png.decode_gray8(_png.SIGNATURE + good[8:33] + _chunk(b"IDAT", idat) + _chunk(b"IEND", b""))
    with pytest.raises(ValueError, match="holds 3 bytes, expected 6"):
        _png.decode_gray8(_png.SIGNATURE + good[8:33] + _chunk(b"IDAT", zlib.compress(b"\x00\x01\x02"))
                          + _chunk(b"IEND", b""))


# --- the REST calls -------------------------------------------------------------------

class Recorder:
    def __init__(self, answer: Any) -> None:
        self.answer = answer
        self.seen: list[tuple[str, str, dict[str, str], bytes]] = []

    def sync(self, request: Any) -> Any:
        self.seen.append((request.method, str(request.url), dict(request.headers), request.read()))
        return self.answer(request)

    async def aio(self, request: Any) -> Any:
        self.seen.append((request.method, str(request.url), dict(request.headers), await request.aread()))
        return self.answer(request)


def _clients(rec: Recorder) -> tuple[AdminClient, AsyncAdminClient]:
    sync = AdminClient("127.0.0.1:9", token="tok")
    sync._http = httpx.Client(base_url=sync.base_url, transport=httpx.MockTransport(rec.sync))
    aio = AsyncAdminClient("127.0.0.1:9", token="tok")
    aio._http = httpx.AsyncClient(base_url=aio.base_url, transport=httpx.MockTransport(rec.aio))
    return sync, aio


ALARM = {"id": "al-1/2", "session_id": "s 1", "profile": "p"}


def _server(r: Any) -> Any:
    path, method = r.url.raw_path.decode().split("?")[0], r.method
    if path == "/v1/alarms":
        return httpx.Response(200, json={"alarms": [ALARM]})
    if path == "/v1/alarms/al-1%2F2" and method == "GET":
        return httpx.Response(200, json=ALARM)
    if path == "/v1/alarms/al-1%2F2/thumbnail":
        return httpx.Response(200, content=b"\x89PNG...", headers={"content-type": "image/png"})
    if path == "/v1/alarms/al-1%2F2/false-alarm":
        return httpx.Response(200, json={**ALARM, "false_alarm": {"by_role": "robot", **json.loads(r.content)}})
    if path == "/v1/alarms/al-marked/false-alarm":
        return httpx.Response(409, json={"error": 'alarm "al-marked" is already marked as a false alarm'})
    if path == "/v1/alarms/al-other/false-alarm":
        return httpx.Response(404, json={"error": 'no alarm "al-other" among the recent alarms'})
    if path == "/v1/alarms/al-viewer/false-alarm":
        return httpx.Response(403, json={"error": "this needs the Robot role"})
    if path == "/v1/profiles/p/nominal":
        return httpx.Response(200, json={"episodes": [{"session_id": "s 1", "finished": True}]})
    if path == "/v1/profiles/p/recalibrate":
        return httpx.Response(202, json={"job": 4})
    if path == "/v1/profiles/file/recalibrate":
        return httpx.Response(409, json={"error": 'profile "file" is a profile file of the server\'s settings'})
    if path == "/v1/jobs/4" and method == "GET":
        return httpx.Response(200, json={"id": 4, "state": "succeeded", "proposal": {"applied_unix_s": None}})
    if path == "/v1/jobs/4/apply":
        return httpx.Response(200, json={"id": 4, "state": "succeeded", "proposal": {"applied_unix_s": 9}})
    return httpx.Response(404, json={"error": "no such route"})


def test_the_alarm_calls_send_what_the_server_reads() -> None:
    rec = Recorder(_server)
    sync, aio = _clients(rec)
    got = [sync.alarms(), sync.alarms(session="s 1", profile="p&q", marked=True), sync.alarm("al-1/2"),
           sync.alarm_thumbnail("al-1/2"), sync.mark_false_alarm("al-1/2", note="a person walked by"),
           sync.mark_false_alarm("al-1/2"), sync.nominal("p"), sync.recalibrate("p"), sync.apply_job(4)]

    async def run() -> list[Any]:
        out = [await aio.alarms(), await aio.alarms(session="s 1", profile="p&q", marked=True),
               await aio.alarm("al-1/2"), await aio.alarm_thumbnail("al-1/2"),
               await aio.mark_false_alarm("al-1/2", note="a person walked by"),
               await aio.mark_false_alarm("al-1/2"), await aio.nominal("p"), await aio.recalibrate("p"),
               await aio.apply_job(4)]
        await aio.aclose()
        return out

    assert asyncio.run(run()) == got
    assert got[0] == [ALARM] and got[3] == b"\x89PNG..." and got[7] == 4
    assert got[4]["false_alarm"] == {"by_role": "robot", "note": "a person walked by"}
    assert got[6] == [{"session_id": "s 1", "finished": True}] and got[8]["proposal"]["applied_unix_s"] == 9
    half = len(rec.seen) // 2
    assert [(m, u) for m, u, _, _ in rec.seen[:half]] == [(m, u) for m, u, _, _ in rec.seen[half:]]
    base = "http://127.0.0.1:9"
    assert [(m, u.removeprefix(base)) for m, u, _, _ in rec.seen[:half]] == [
        ("GET", "/v1/alarms"),
        ("GET", "/v1/alarms?session=s+1&profile=p%26q&marked=true"),
        ("GET", "/v1/alarms/al-1%2F2"),
        ("GET", "/v1/alarms/al-1%2F2/thumbnail"),
        ("POST", "/v1/alarms/al-1%2F2/false-alarm"),
        ("POST", "/v1/alarms/al-1%2F2/false-alarm"),
        ("GET", "/v1/profiles/p/nominal"),
        ("POST", "/v1/profiles/p/recalibrate"),
        ("POST", "/v1/jobs/4/apply"),
    ]
    marks = [(h, b) for m, u, h, b in rec.seen if u.endswith("/false-alarm")]
    assert [json.loads(b) for _, b in marks] == [{"note": "a person walked by"}, {"note": ""}] * 2
    assert all(h["content-type"] == "application/json" for h, _ in marks)
    assert all(h["authorization"] == "Bearer tok" for _, _, h, _ in rec.seen)


def test_alarm_errors_say_what_to_do() -> None:
    sync, aio = _clients(Recorder(_server))
    with pytest.raises(Conflict) as e:
        sync.mark_false_alarm("al-marked")
    assert str(e.value) == ('POST /v1/alarms/al-marked/false-alarm: HTTP 409: alarm "al-marked" is already '
                            'marked as a false alarm (an alarm is marked once; the first mark stays)')
    assert e.value.status == 409 and e.value.hint == "an alarm is marked once; the first mark stays"
    with pytest.raises(NotFound, match="robot token sees only the alarms of its own sessions"):
        sync.mark_false_alarm("al-other")
    with pytest.raises(Forbidden, match=r"Robot role \(marking a false alarm needs a robot or admin token"):
        sync.mark_false_alarm("al-viewer")
    with pytest.raises(Conflict, match='profile "file" is a profile file') as e:
        sync.recalibrate("file")
    assert e.value.hint == ""

    async def run() -> None:
        with pytest.raises(Conflict, match='profile "file"'):
            await aio.recalibrate("file")
        await aio.aclose()

    asyncio.run(run())
    # Refused before anything is sent: an empty id would name another route.
    for call in (lambda: sync.mark_false_alarm(" "), lambda: sync.alarm(""), lambda: sync.recalibrate("")):
        with pytest.raises(ValueError, match="must not be empty"):
            call()
    with pytest.raises(TypeError, match="note must be a string"):
        sync.mark_false_alarm("al-1", note=3)  # type: ignore[arg-type]


def test_recalibrate_and_wait_follows_the_job_and_applies_it() -> None:
    rec = Recorder(_server)
    sync, _ = _clients(rec)
    assert sync.recalibrate_and_wait("p", poll_s=0)["proposal"] == {"applied_unix_s": None}
    assert sync.recalibrate_and_wait("p", apply=True, poll_s=0)["proposal"] == {"applied_unix_s": 9}
    assert [u.rsplit("/v1/", 1)[1] for _, u, _, _ in rec.seen] == [
        "profiles/p/recalibrate", "jobs/4", "profiles/p/recalibrate", "jobs/4", "jobs/4/apply"]


def test_the_command_line_parses_the_alarm_commands(capsys: pytest.CaptureFixture[str]) -> None:
    p = build_parser()
    a = p.parse_args(["alarms", "list", "--session", "s", "--marked"])
    assert (a.command, a.action, a.session, a.profile, a.marked) == ("alarms", "list", "s", None, True)
    a = p.parse_args(["--token", "t", "alarms", "mark", "al-1", "--note", "cat"])
    assert (a.action, a.id, a.note, a.token) == ("mark", "al-1", "cat", "t")
    a = p.parse_args(["recalibrate", "p", "--apply"])
    assert (a.profile, a.apply, a.no_wait, a.timeout) == ("p", True, False, 3600.0)
    a = p.parse_args(["stream", "x.mcap", "--profile", "p", "--anomaly-maps", "maps"])
    assert a.anomaly_maps == "maps"
    assert p.parse_args(["profiles", "nominal", "p"]).action == "nominal"
    with pytest.raises(SystemExit) as e:
        p.parse_args(["jobs", "3", "--cancel", "--apply"])
    assert e.value.code == 2
    capsys.readouterr()
    assert main(["--api", "http://127.0.0.1:9", "jobs", "--apply"]) == 2
    assert "need a job id" in capsys.readouterr().err
