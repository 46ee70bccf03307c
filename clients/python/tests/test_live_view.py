"""The live view (``/ui``) in a real headless browser against the real ``vamos serve``.

A robot streams a simulated episode over gRPC (raw stubs, ``anomaly_maps`` on) while
Debian's chromium, driven by selenium through chromium-driver, checks that the page:
refuses to show anything without a token, lists the session for a viewer, updates the
timeline, draws the anomaly map over the latest frame, lists the alarm with its
thumbnail, does not let a viewer mark it (and the API refuses a viewer's mark, nothing
stored), lets a robot token mark it as a false alarm (which reaches the data directory),
and says so when the session has ended.

The profile makes every frame an alarm frame (``[thresholds] alarm = 0.0``), so the
alarm is certain and starts at the third frame (3 of 5). Skipped when chromium or
chromium-driver is missing, unless ``VAMOS_REQUIRE_BROWSER_TESTS=1`` (CI sets it), which
makes that a failure. ``VAMOS_UI_SCREENSHOT=FILE`` saves a screenshot of the page.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any, Callable

import pytest

from _server import ADMIN, ROBOT, ROOT, SIM, Server, vamos_bin

grpc = pytest.importorskip("grpc")
mcap_reader = pytest.importorskip("mcap.reader")
mcap_ros2_decoder = pytest.importorskip("mcap_ros2.decoder")

VIEWER = "py-viewer-token"
EPISODE = SIM / "test" / "test_0001_external_push.mcap"
MODEL = ROOT / "tests" / "fixtures" / "model" / "tiny_trained.vamos"


def _browser_binaries() -> "tuple[str, str] | None":
    chrome = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    driver = shutil.which("chromedriver") or (
        "/usr/lib/chromium/chromedriver" if Path("/usr/lib/chromium/chromedriver").exists() else None)
    return (chrome, driver) if chrome and driver else None


def _need_browser() -> "tuple[str, str]":
    found = _browser_binaries()
    try:
        import selenium  # noqa: F401
    except ImportError:
        found = None
    if found is None:
        if os.environ.get("VAMOS_REQUIRE_BROWSER_TESTS") == "1":
            pytest.fail("VAMOS_REQUIRE_BROWSER_TESTS=1 but chromium, chromium-driver or selenium is missing "
                        "(apt-get install chromium chromium-driver; pip install selenium)")
        pytest.skip("chromium + chromium-driver + selenium not installed")
    return found


def _call(server: Server, method: str, path: str, token: "str | None",
          body: "bytes | None" = None) -> "tuple[int, Any]":
    req = urllib.request.Request(server.rest + path, data=body, method=method)
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    if body is not None:
        req.add_header("Content-Type", "application/json")
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            raw = r.read()
            return r.status, (json.loads(raw) if r.headers.get_content_type() == "application/json" else raw)
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read() or b"{}")


def _requests(pb: Any, session_id: str, pace_s: float, release: threading.Event):
    """The episode as a robot streams it: open (with anomaly maps), then its messages in
    log-time order, images ``pace_s`` apart; then the session is held open (a phase marker
    every second keeps it from idling out) until ``release`` is set (at most 120 s)."""
    with open(EPISODE, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_ros2_decoder.DecoderFactory()])
        messages = list(reader.iter_decoded_messages(log_time_order=True))
    yield pb.StreamRequest(open=pb.OpenSession(
        robot_id="browser-robot", profile="sim-arm", session_id=session_id, task="place_book",
        anomaly_maps=True))
    for schema, _channel, _message, m in messages:
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec if hasattr(m, "header") else 0
        if schema.name == "sensor_msgs/msg/Image":
            time.sleep(pace_s)
            yield pb.StreamRequest(image=pb.Image(
                stamp_ns=stamp, encoding=m.encoding, width=m.width, height=m.height,
                step=m.step, big_endian=bool(m.is_bigendian), data=bytes(m.data)))
        elif schema.name == "sensor_msgs/msg/JointState":
            yield pb.StreamRequest(joints=pb.JointState(
                stamp_ns=stamp, names=list(m.name), positions=list(m.position)))
    deadline = time.monotonic() + 120
    while not release.wait(1.0) and time.monotonic() < deadline:
        yield pb.StreamRequest(phase=pb.PhaseMarker(stamp_ns=stamp, phase="hold"))


class Robot(threading.Thread):
    """Streams the episode in the background, keeping every response."""

    def __init__(self, server: Server, session_id: str, pace_s: float) -> None:
        super().__init__(daemon=True)
        from vamos.v1 import monitor_pb2, monitor_pb2_grpc

        self.pb, self.grpc_mod = monitor_pb2, monitor_pb2_grpc
        self.server, self.session_id, self.pace_s = server, session_id, pace_s
        self.responses: list[Any] = []
        self.error: "BaseException | None" = None
        #: Set to let the session end.
        self.release = threading.Event()

    def run(self) -> None:
        try:
            with grpc.insecure_channel(self.server.grpc) as channel:
                stub = self.grpc_mod.MonitorStub(channel)
                for r in stub.Stream(_requests(self.pb, self.session_id, self.pace_s, self.release),
                                     metadata=[("authorization", f"Bearer {ROBOT}")]):
                    self.responses.append(r)
        except BaseException as e:  # noqa: BLE001 - reported by the test
            self.error = e


def _wait(what: str, check: Callable[[], Any], timeout_s: float = 30.0) -> Any:
    deadline = time.monotonic() + timeout_s
    last: Any = None
    while time.monotonic() < deadline:
        try:
            last = check()
        except Exception as e:  # noqa: BLE001 - the DOM may be mid-update; try again
            last = e
        if last and not isinstance(last, Exception):
            return last
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what} (last: {last!r})")


@pytest.fixture
def browser():
    chrome, driver_path = _need_browser()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = chrome
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
              "--window-size=1400,1000"):
        opts.add_argument(a)
    d = webdriver.Chrome(service=Service(driver_path), options=opts)
    yield d
    d.quit()


def _click_row(d: Any, session_id: str) -> None:
    """Clicks the session's row (found and clicked in one script: the list is redrawn
    twice a second, so a row found by one call may be gone by the next)."""
    _wait(f"the row of {session_id}", lambda: d.execute_script(
        "const r = [...document.querySelectorAll('#sessions tbody tr')]"
        ".find((x) => x.dataset.id === arguments[0]); if (r) r.click(); return !!r;", session_id))


def _sign_in(d: Any, token: str) -> None:
    from selenium.webdriver.common.by import By

    d.find_element(By.ID, "signout").click()
    d.find_element(By.ID, "token").send_keys(token)
    d.find_element(By.ID, "signin").click()


def test_live_view_in_a_real_browser(browser: Any, tmp_path: Path) -> None:
    from selenium.webdriver.common.by import By

    d = browser
    server = Server(vamos_bin(), tmp_path / "server", env={"VAMOS_VIEWER_TOKEN": VIEWER},
                    profile_keys=f'model = "{MODEL}"\n', profile_extra="[thresholds]\nalarm = 0.0\n")
    robot = Robot(server, "ui-session", pace_s=0.12)
    try:
        robot.start()
        _wait("the session to open", lambda: _call(server, "GET", "/v1/live", VIEWER)[1]["sessions"]["sessions"])

        # Without a token: the page shows nothing and says why; the API refuses.
        d.get(server.rest + "/ui")
        _wait("the refusal", lambda: "needs a token" in d.find_element(By.ID, "message").text)
        assert d.find_element(By.ID, "role").text == "not signed in"
        assert d.find_elements(By.CSS_SELECTOR, "#sessions tbody tr") == []
        for path in ("/v1/live", "/v1/alarms", "/v1/sessions/ui-session/timeline", "/v1/whoami"):
            assert _call(server, "GET", path, None)[0] == 401, path
        # A bad token is refused too.
        _sign_in(d, "not-a-token")
        _wait("the bad token's refusal", lambda: "invalid token" in d.find_element(By.ID, "message").text)

        # A viewer sees the session, its timeline, the frame with the map, the alarm.
        _sign_in(d, VIEWER)
        _wait("the viewer role", lambda: d.find_element(By.ID, "role").text == "role: viewer")
        text = _wait("the session row", lambda: d.execute_script(
            "const r = document.querySelector('#sessions tbody tr[data-id=\"ui-session\"]');"
            "return r && r.textContent"))
        assert "browser-robot" in text and "sim-arm" in text
        _click_row(d, "ui-session")
        canvas = d.find_element(By.ID, "timeline")
        first = _wait("timeline points", lambda: int(canvas.get_attribute("data-points")) or None)
        _wait("the timeline to grow", lambda: int(canvas.get_attribute("data-points")) > first + 5)
        overlay = d.find_element(By.ID, "overlay")
        _wait("the frame", lambda: int(overlay.get_attribute("data-frame")) >= 1)
        _wait("the anomaly map", lambda: int(overlay.get_attribute("data-map")) >= 1)
        item = _wait("an alarm", lambda: d.find_element(By.CSS_SELECTOR, "#alarms li"))
        alarm_id = item.get_attribute("data-id")
        img = item.find_element(By.TAG_NAME, "img")
        _wait("the alarm's thumbnail", lambda: d.execute_script(
            "return arguments[0].complete && arguments[0].naturalWidth", img) > 0)
        button = item.find_element(By.CSS_SELECTOR, "button.mark")
        assert not button.is_enabled(), "a viewer must not be offered the mark"
        shot = os.environ.get("VAMOS_UI_SCREENSHOT")
        if shot:
            time.sleep(1.0)
            d.save_screenshot(shot)

        # The API refuses a viewer's mark; nothing is stored.
        status, body = _call(server, "POST", f"/v1/alarms/{alarm_id}/false-alarm", VIEWER, b"{}")
        assert status == 403, body
        assert _call(server, "GET", "/v1/alarms?marked=true", ADMIN) == (200, {"alarms": []})
        assert not (tmp_path / "server" / "data" / "alarms").exists() or not any(
            (tmp_path / "server" / "data" / "alarms").iterdir())
        # Unknown ids: clear 404s.
        status, body = _call(server, "POST", "/v1/alarms/al-nope/false-alarm", ROBOT, b"{}")
        assert status == 404 and "no alarm" in body["error"], body
        status, body = _call(server, "GET", "/v1/sessions/nope/timeline", VIEWER)
        assert status == 404 and "no open session" in body["error"], body

        # A robot token marks it on the page; the mark reaches the data directory.
        _sign_in(d, ROBOT)
        _wait("the robot role", lambda: d.find_element(By.ID, "role").text == "role: robot")
        _click_row(d, "ui-session")
        button = _wait("the mark button", lambda: [
            b for b in d.find_elements(By.CSS_SELECTOR, f'#alarms li[data-id="{alarm_id}"] button.mark') if b.is_enabled()])[0]
        button.click()
        _wait("the confirmation", lambda: "marked as a false alarm" in d.find_element(By.ID, "message").text)
        status, body = _call(server, "GET", "/v1/alarms?marked=true", ADMIN)
        assert status == 200 and [a["id"] for a in body["alarms"]] == [alarm_id], body
        assert body["alarms"][0]["false_alarm"]["by_role"] == "robot"
        stored = tmp_path / "server" / "data" / "alarms" / f"{alarm_id}.json"
        assert stored.is_file()
        # Marking twice is refused, the first mark stays.
        status, body = _call(server, "POST", f"/v1/alarms/{alarm_id}/false-alarm", ADMIN, b"{}")
        assert status == 409, body

        # The robot's stream carried the alarm's start, with its thresholds and components.
        robot.release.set()
        robot.join(timeout=120)
        assert robot.error is None, robot.error
        alarms = [r.alarm for r in robot.responses if r.WhichOneof("message") == "alarm"]
        assert alarms and alarms[0].alarm_id == alarm_id, alarms[:1]
        assert alarms[0].edge == robot.pb.AlarmEvent.EDGE_STARTED
        scores = [r.score for r in robot.responses if r.WhichOneof("message") == "score"]
        # 3 of the last 5 flags start it (the first frame of a stream has no motion to
        # judge and is not flagged; every later one is, with alarm threshold 0).
        flags = [s.anomaly for s in scores]
        start = next(i for i in range(len(flags)) if sum(flags[max(0, i - 4):i + 1]) >= 3)
        assert sum(flags) >= len(flags) - 1
        assert alarms[0].alarm_threshold == 0.0 and alarms[0].start_frame == scores[start].frame
        with_e_o = [s for s in scores if s.HasField("e_o")]
        assert with_e_o and all(s.anomaly_map[:8] == b"\x89PNG\r\n\x1a\n" for s in with_e_o)

        # The session has ended: the page says so instead of showing stale data.
        _wait("the page to notice the end", lambda: "no open session" in d.find_element(By.ID, "message").text)

        # The marked alarm kept the session's recording: it is the profile's nominal set.
        recording = json.loads(stored.read_text())["body"]["recording"]
        def nominal() -> Any:
            status, body = _call(server, "GET", "/v1/profiles/sim-arm/nominal", VIEWER)
            assert status == 200, body
            return body["episodes"] if body["episodes"] and body["episodes"][0]["finished"] else None
        (episode,) = _wait("the nominal set", nominal)
        assert episode["session_id"] == "ui-session" and episode["alarms"] == [alarm_id]
        assert episode["recording"] == recording and episode["bytes"] > 0
        assert (tmp_path / "server" / "data" / "recordings" / recording).is_file()
        # ... and the page lists it under its profile (refreshed every 10 s).
        _wait("the nominal set on the page", lambda: "ui-session" in d.find_element(By.ID, "profiles").text
              and "1 nominal episode(s)" in d.find_element(By.ID, "profiles").text, timeout_s=40)
    finally:
        robot.release.set()
        server.stop()


def _topics(path: Path) -> "dict[str, list[Any]]":
    """Every message of a bag by topic: ``(schema name, decoded message)``."""
    out: "dict[str, list[Any]]" = {}
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_ros2_decoder.DecoderFactory()])
        for schema, channel, _message, m in reader.iter_decoded_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append((schema.name, m))
    return out


def _check_scored_bag(path: Path, server: Server) -> None:
    topics = _topics(path)
    source = _topics(EPISODE)
    # The input's context, as recorded.
    for topic in ("/camera/image_raw", "/camera/camera_info", "/joint_states", "/robot_description"):
        assert len(topics.get(topic, [])) == len(source[topic]), topic
    info = topics["/camera/camera_info"][0][1]
    assert (info.width, info.height) == (source["/camera/camera_info"][0][1].width,
                                         source["/camera/camera_info"][0][1].height)
    # The thresholds once, the anomaly map with every frame that has e_o.
    (schema, thr), = topics["/vamos/thresholds"]
    assert schema == "std_msgs/msg/String" and json.loads(thr.data) == {
        # `fusion = "auto"` is the calibrated fusion; without fitted scales (no calibration)
        # each detector's raw value meets the alarm threshold itself.
        "alarm": 0.0, "e_c": 0.0, "e_b": 0.0, "e_o": 0.0, "e_r": 0.0, "e_k": 0.0}
    maps = topics["/vamos/anomaly_map"]
    assert maps and len(maps) == len(topics["/vamos/e_o"])
    for schema, m in maps:
        assert schema == "sensor_msgs/msg/Image" and m.encoding == "mono8"
        assert len(m.data) == m.width * m.height and m.step == m.width
    assert any(max(m.data) > 0 for _, m in maps)
    # Every topic the profile's Foxglove layout (`vamos layout`) shows is in the bag: the
    # camera, the map, and the detectors the profile runs (no e_k: it is not calibrated).
    import subprocess

    made = subprocess.run([str(server.bin), "layout", "--profile", str(server.profile), str(path)],
                          capture_output=True, text=True, env=server.env)
    assert made.returncode == 0, made.stderr
    named = set(re.findall(r'"(/[a-z_]+/[a-z_]+)(?:\.[a-z_]+)?"', made.stdout))
    assert {"/camera/image_raw", "/vamos/anomaly_map", "/vamos/score", "/vamos/e_o", "/vamos/e_r"} <= named, named
    assert "/vamos/e_k" not in named, named
    assert named <= set(topics), sorted(named - set(topics))


def test_scored_bags_carry_the_map_the_context_and_the_thresholds(tmp_path: Path) -> None:
    server = Server(vamos_bin(), tmp_path / "server", profile_keys=f'model = "{MODEL}"\n',
                    profile_extra="[thresholds]\nalarm = 0.0\n")
    try:
        # vamos score --mcap
        out = tmp_path / "scored"
        import subprocess

        run = subprocess.run([str(server.bin), "score", "--profile", str(server.profile), str(EPISODE),
                              "--out", str(out), "--mcap", "--no-progress"],
                             capture_output=True, text=True, env=server.env)
        assert run.returncode == 0, run.stderr
        _check_scored_bag(out / f"{EPISODE.stem}.scored.mcap", server)
        # The REST-scored bag.
        req = urllib.request.Request(f"{server.rest}/v1/episodes:score?profile=sim-arm&name={EPISODE.stem}",
                                     data=EPISODE.read_bytes(), method="POST")
        req.add_header("Authorization", f"Bearer {ROBOT}")
        req.add_header("Accept", "application/x-mcap")
        with urllib.request.urlopen(req, timeout=120) as r:
            assert r.status == 200
            (tmp_path / "rest.mcap").write_bytes(r.read())
        _check_scored_bag(tmp_path / "rest.mcap", server)
    finally:
        server.stop()


def test_the_api_reference_page_shows_every_operation_and_schema(browser: Any, tmp_path: Path) -> None:
    """``/docs`` in the browser: built from the served document, one entry per operation
    and per schema, a request body's members (a profile's pipeline) opened on click, and
    the filter narrowing the list. No token is needed (it reads only ``/openapi.json``)."""
    from selenium.webdriver.common.by import By

    server = Server(vamos_bin(), tmp_path / "server")
    try:
        with urllib.request.urlopen(f"{server.rest}/openapi.json", timeout=30) as r:
            doc = json.loads(r.read())
        operations = sum(len(item) for item in doc["paths"].values())
        d = browser
        d.get(f"{server.rest}/docs")
        _wait("the page to render", lambda: d.find_element(By.TAG_NAME, "body").get_attribute("data-ready"))
        assert d.find_element(By.ID, "message").text == ""
        ops = d.find_elements(By.CSS_SELECTOR, "#operations > details")
        assert len(ops) == operations, (len(ops), operations)
        schemas = d.find_elements(By.CSS_SELECTOR, "#schemas > details")
        assert len(schemas) == len(doc["components"]["schemas"])
        assert doc["info"]["version"] in d.find_element(By.ID, "version").text

        put = d.find_element(By.ID, "put-/v1/profiles/{name}")
        put.find_element(By.TAG_NAME, "summary").click()
        assert "admin" in put.text and "ProfileSpec" in put.text
        # The body's members, and a member's own members one click further.
        pipeline = _wait("the pipeline member", lambda: [
            e for e in put.find_elements(By.CSS_SELECTOR, ".schema details > summary")
            if e.text.startswith("pipeline")])
        pipeline[0].click()
        _wait("the pipeline's members", lambda: "temporal_window" in put.text and "stride" in put.text)

        box = d.find_element(By.ID, "filter")
        box.send_keys("episodes:score")
        shown = [e for e in d.find_elements(By.CSS_SELECTOR, "#operations > details") if e.is_displayed()]
        assert [e.get_attribute("id") for e in shown] == ["post-/v1/episodes:score"]
        if os.environ.get("VAMOS_UI_SCREENSHOT"):
            d.save_screenshot(str(Path(os.environ["VAMOS_UI_SCREENSHOT"]).with_suffix(".docs.png")))
    finally:
        server.stop()
