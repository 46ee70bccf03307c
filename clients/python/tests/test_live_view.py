"""The live view (``/ui``) in a real headless browser against the real ``vamos serve``.

A robot streams a simulated episode over gRPC (raw stubs, ``anomaly_maps`` on) while
Debian's chromium, driven by selenium through chromium-driver, checks that the page:
refuses to show anything without a token, lists the robot and its session for a viewer,
updates the timeline, draws the anomaly map over the latest frame, lists the alarm with
its thumbnail, does not let a viewer mark it (and the API refuses a viewer's mark, nothing
stored), lets a robot token mark it as a false alarm (which reaches the data directory),
and keeps the session, marked as ended, when it ends.

Then two robots, each with two sessions in sequence (the last one sent in a burst that a
one-image queue cannot hold, so it is degraded): while it runs the page shows the robot
degraded; after all four ended the page still shows both robots' sessions with their
timelines (time axes labelled) and alarms, an ended session's alarm is marked false from
the page (in its session's list and in the recent alarms) and the marks reach the server,
the page fits a 1400 px window without a horizontal scroll, and a restarted server shows
the same ended sessions and alarms again.

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


def _requests(pb: Any, session_id: str, pace_s: float, release: threading.Event,
              robot_id: str = "browser-robot"):
    """The episode as a robot streams it: open (with anomaly maps), then its messages in
    log-time order, images ``pace_s`` apart (0: all at once); then the session is held open
    (a phase marker every second keeps it from idling out) until ``release`` is set (at
    most 120 s)."""
    with open(EPISODE, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_ros2_decoder.DecoderFactory()])
        messages = list(reader.iter_decoded_messages(log_time_order=True))
    yield pb.StreamRequest(open=pb.OpenSession(
        robot_id=robot_id, profile="sim-arm", session_id=session_id, task="place_book",
        anomaly_maps=True))
    for schema, _channel, _message, m in messages:
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec if hasattr(m, "header") else 0
        if schema.name == "sensor_msgs/msg/Image":
            if pace_s:
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

    def __init__(self, server: Server, session_id: str, pace_s: float,
                 robot_id: str = "browser-robot") -> None:
        super().__init__(daemon=True)
        from vamos.v1 import monitor_pb2, monitor_pb2_grpc

        self.pb, self.grpc_mod = monitor_pb2, monitor_pb2_grpc
        self.server, self.session_id, self.pace_s = server, session_id, pace_s
        self.robot_id = robot_id
        self.responses: list[Any] = []
        self.error: "BaseException | None" = None
        #: Set to let the session end.
        self.release = threading.Event()

    def run(self) -> None:
        try:
            with grpc.insecure_channel(self.server.grpc) as channel:
                stub = self.grpc_mod.MonitorStub(channel)
                for r in stub.Stream(_requests(self.pb, self.session_id, self.pace_s, self.release,
                                               self.robot_id),
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


def _click_session(d: Any, session_id: str, state: str = "") -> None:
    """Clicks the session's button in its robot's row (``state``: only when it is ``live``
    or ``ended``); found and clicked in one script: the rows are redrawn twice a second,
    so a button found by one call may be gone by the next."""
    _wait(f"the button of {session_id}", lambda: d.execute_script(
        "const b = [...document.querySelectorAll('#robots button.session')]"
        ".find((x) => x.dataset.id === arguments[0] && (!arguments[1] || x.dataset.state === arguments[1]));"
        "if (b) b.click(); return !!b;", session_id, state))


def _robot_row(d: Any, robot_id: str) -> "dict[str, Any] | None":
    """The robot's row as ``{state, text, sessions: {id: [state, classes]}, order: [id]}``
    (``order``: the session buttons as shown)."""
    row = d.execute_script(
        "const r = [...document.querySelectorAll('#robots tbody tr')].find((x) => x.dataset.robot === arguments[0]);"
        "if (!r) return null;"
        "const s = [...r.querySelectorAll('button.session')].map((b) => [b.dataset.id, b.dataset.state, b.className]);"
        "return {state: r.dataset.state, text: r.textContent, sessions: s};", robot_id)
    if row is not None:
        row["order"] = [b[0] for b in row["sessions"]]
        row["sessions"] = {b[0]: b[1:] for b in row["sessions"]}
    return row


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
        assert d.find_elements(By.CSS_SELECTOR, "#robots tbody tr") == []
        for path in ("/v1/live", "/v1/alarms", "/v1/sessions/ui-session/timeline", "/v1/whoami"):
            assert _call(server, "GET", path, None)[0] == 401, path
        # A bad token is refused too.
        _sign_in(d, "not-a-token")
        _wait("the bad token's refusal", lambda: "invalid token" in d.find_element(By.ID, "message").text)

        # A viewer sees the session, its timeline, the frame with the map, the alarm.
        _sign_in(d, VIEWER)
        _wait("the viewer role", lambda: d.find_element(By.ID, "role").text == "role: viewer")
        row = _wait("the robot's row", lambda: _robot_row(d, "browser-robot"))
        assert "sim-arm" in row["text"] and row["sessions"]["ui-session"][0] == "live", row
        _click_session(d, "ui-session")
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
        _click_session(d, "ui-session")
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

        # The session has ended: the page keeps it, as ended, with its timeline and alarm.
        _wait("the page to notice the end", lambda: "ended" in d.find_element(By.ID, "selected-title").text)
        assert int(canvas.get_attribute("data-points")) > 0
        assert d.find_elements(By.CSS_SELECTOR, f'#alarms li[data-id="{alarm_id}"].marked')
        # What the profile cannot do is said on the page: not calibrated, so no e_k.
        notes = d.find_element(By.ID, "profile-notes")
        assert not notes.get_attribute("hidden") and "e_k does not run" in notes.text, notes.text
        _wait("the robot's row to say ended", lambda: (_robot_row(d, "browser-robot") or {}).get("state") == "ended")

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


def _no_horizontal_scroll(d: Any) -> "dict[str, int]":
    """The page's and the robots table's widths against the window's."""
    return d.execute_script(
        "const e = document.documentElement, t = document.getElementById('robots');"
        "return {window: window.innerWidth, client: e.clientWidth, page: e.scrollWidth,"
        " table: t.scrollWidth, table_box: t.clientWidth};")


def test_robots_keep_their_last_sessions_and_alarms(browser: Any, tmp_path: Path) -> None:
    """Two robots, each with two sessions in sequence; the page after all four ended, a
    false alarm of an ended session marked from it, and a restart."""
    from selenium.webdriver.common.by import By

    d = browser
    # A one-image queue: the burst of arm-b's second session loses images (degraded).
    env = {"VAMOS_VIEWER_TOKEN": VIEWER, "VAMOS_SERVICE__QUEUE_DEPTH": "1"}
    keys = f'model = "{MODEL}"\n'
    extra = "[thresholds]\nalarm = 0.0\n"
    server = Server(vamos_bin(), tmp_path / "server", env=env, profile_keys=keys, profile_extra=extra)
    robots: "list[Robot]" = []

    def run(session_id: str, robot_id: str, pace_s: float, hold: bool = False) -> Robot:
        r = Robot(server, session_id, pace_s=pace_s, robot_id=robot_id)
        if not hold:
            r.release.set()  # the session ends after its last image
        robots.append(r)
        r.start()
        return r

    def finish(r: Robot) -> None:
        r.release.set()
        r.join(timeout=120)
        assert not r.is_alive() and r.error is None, r.error

    try:
        d.get(server.rest + "/ui")
        _sign_in(d, ROBOT)
        _wait("the robot role", lambda: d.find_element(By.ID, "role").text == "role: robot")
        # First sessions, side by side; each robot is a row while they run.
        first = [run("arm-a-1", "arm-a", 0.1), run("arm-b-1", "arm-b", 0.1)]
        _wait("both robots live", lambda: all(
            (_robot_row(d, r) or {}).get("state") in ("live", "degraded") for r in ("arm-a", "arm-b")))
        for r in first:
            finish(r)
        # Second sessions: arm-b's sent in one burst and held open.
        second = [run("arm-a-2", "arm-a", 0.1), run("arm-b-2", "arm-b", 0.0, hold=True)]
        row = _wait("arm-b degraded", lambda: (lambda r: r if r and r["state"] == "degraded" else None)(
            _robot_row(d, "arm-b")), timeout_s=60)
        assert "degraded" in row["text"] and "degraded" in row["sessions"]["arm-b-2"][1], row
        status, live = _call(server, "GET", "/v1/live", VIEWER)
        (b2,) = [x["summary"] for r in live["robots"]["robots"] if r["robot_id"] == "arm-b" for x in r["sessions"]]
        assert b2["degraded"] and b2["frames_lost"] > 0, b2
        for r in second:
            finish(r)

        # Both robots keep both sessions, ended, newest first, on the page and in the API.
        def ended_rows() -> Any:
            rows = {r: _robot_row(d, r) for r in ("arm-a", "arm-b")}
            ok = all(x and x["state"] == "ended" and len(x["sessions"]) == 2
                     and all(v[0] == "ended" for v in x["sessions"].values()) for x in rows.values())
            return rows if ok else None
        rows = _wait("both robots' ended sessions", ended_rows)
        assert rows["arm-a"]["order"] == ["arm-a-2", "arm-a-1"], rows
        assert rows["arm-b"]["order"] == ["arm-b-2", "arm-b-1"], rows
        assert "degraded" in rows["arm-b"]["sessions"]["arm-b-2"][1]
        status, live = _call(server, "GET", "/v1/live", VIEWER)
        assert status == 200 and live["sessions"]["sessions"] == [], live["sessions"]
        ended = {r["robot_id"]: [e["id"] for e in r["ended"]] for r in live["robots"]["robots"]}
        assert ended == {"arm-a": ["arm-a-2", "arm-a-1"], "arm-b": ["arm-b-2", "arm-b-1"]}, ended

        # An ended session: its whole timeline with a labelled time axis, and its alarm.
        _click_session(d, "arm-a-1", "ended")
        canvas = d.find_element(By.ID, "timeline")
        _wait("arm-a-1's timeline", lambda: int(canvas.get_attribute("data-points")) >= 20)
        assert "ended" in d.find_element(By.ID, "selected-title").text
        ticks = canvas.get_attribute("data-ticks").split(",")
        assert len(ticks) >= 3 and all(re.fullmatch(r"\d+(\.\d+)? s", t) for t in ticks), ticks
        seconds = [float(t[:-2]) for t in ticks]
        assert seconds == sorted(seconds) and seconds[-1] >= 2.0, seconds  # 29 frames 0.1 s apart
        status, timeline = _call(server, "GET", "/v1/sessions/arm-a-1/timeline", VIEWER)
        assert status == 200 and timeline["session"]["state"] == "ended", timeline["session"]
        assert len(timeline["points"]) == int(canvas.get_attribute("data-points"))
        item = _wait("arm-a-1's alarm", lambda: d.find_element(By.CSS_SELECTOR, "#alarms li"))
        a1_alarm = item.get_attribute("data-id")
        assert item.get_attribute("data-session") == "arm-a-1"
        button = _wait("the mark button", lambda: [
            b for b in d.find_elements(By.CSS_SELECTOR, f'#alarms li[data-id="{a1_alarm}"] button.mark')
            if b.is_enabled()])[0]
        button.click()
        _wait("the confirmation", lambda: f"Alarm {a1_alarm} marked" in d.find_element(By.ID, "message").text)
        status, alarms = _call(server, "GET", "/v1/sessions/arm-a-1/alarms", ROBOT)
        assert status == 200 and alarms["alarms"][0]["false_alarm"]["by_role"] == "robot", alarms
        _wait("the mark on the page", lambda: d.find_elements(
            By.CSS_SELECTOR, f'#alarms li[data-id="{a1_alarm}"].marked'))

        # The recent alarms list every session's alarms (the paced sessions alarm for
        # certain; the burst's frames after a gap cannot); arm-b-1's is marked from there.
        status, body = _call(server, "GET", "/v1/alarms", VIEWER)
        with_alarms = {a["session_id"] for a in body["alarms"]}
        assert with_alarms >= {"arm-a-1", "arm-a-2", "arm-b-1"}, with_alarms
        _wait("every session's alarms in the recent list", lambda: {
            i.get_attribute("data-session") for i in d.find_elements(By.CSS_SELECTOR, "#recent-alarms li")
        } == with_alarms)
        b1_alarm = _wait("arm-b-1's mark button", lambda: d.execute_script(
            "const li = document.querySelector('#recent-alarms li[data-session=\"arm-b-1\"]');"
            "const b = li && li.querySelector('button.mark');"
            "if (!b || b.disabled) return null; b.click(); return li.dataset.id;"))
        _wait("the second confirmation", lambda: f"Alarm {b1_alarm} marked" in d.find_element(By.ID, "message").text)
        status, marked = _call(server, "GET", "/v1/alarms?marked=true", ADMIN)
        assert status == 200 and sorted(a["id"] for a in marked["alarms"]) == sorted([a1_alarm, b1_alarm]), marked
        assert (tmp_path / "server" / "data" / "alarms" / f"{b1_alarm}.json").is_file()

        # 1400 px: nothing wider than the window.
        widths = _no_horizontal_scroll(d)
        assert widths["window"] == 1400 or widths["client"] >= 1380, widths
        assert widths["page"] <= widths["client"] and widths["table"] <= widths["table_box"], widths
        shot = os.environ.get("VAMOS_UI_SCREENSHOT")
        if shot:
            d.save_screenshot(str(Path(shot).with_suffix(".robots.png")))
    finally:
        for r in robots:
            r.release.set()
        server.stop()

    # A restart: the ended sessions come back from the data directory with their alarms,
    # the marks included (a viewer sees them; the robot token's identity is not stored).
    server = Server(vamos_bin(), tmp_path / "server", env=env, profile_keys=keys, profile_extra=extra)
    try:
        status, live = _call(server, "GET", "/v1/live", VIEWER)
        ended = {r["robot_id"]: [e["id"] for e in r["ended"]] for r in live["robots"]["robots"]}
        assert ended == {"arm-a": ["arm-a-2", "arm-a-1"], "arm-b": ["arm-b-2", "arm-b-1"]}, ended
        status, body = _call(server, "GET", "/v1/alarms", VIEWER)
        by_id = {a["id"]: a for a in body["alarms"]}
        assert {a["session_id"] for a in body["alarms"]} == with_alarms
        assert by_id[a1_alarm]["false_alarm"] and by_id[b1_alarm]["false_alarm"], by_id
        status, timeline = _call(server, "GET", "/v1/sessions/arm-a-1/timeline", VIEWER)
        assert status == 200 and timeline["points"], timeline
        d.get(server.rest + "/ui")
        _sign_in(d, VIEWER)
        _wait("the restored rows", lambda: all(
            len((_robot_row(d, r) or {}).get("sessions", {})) == 2 for r in ("arm-a", "arm-b")))
        _click_session(d, "arm-b-2", "ended")
        _wait("arm-b-2's restored timeline", lambda: int(
            d.find_element(By.ID, "timeline").get_attribute("data-points")) > 0)
        assert not d.find_element(By.ID, "degraded").get_attribute("hidden"), "arm-b-2 lost images"
    finally:
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
