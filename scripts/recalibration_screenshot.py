#!/usr/bin/env python3
"""Screenshot of a recalibration proposal on the live view (docs/img/recalibration.png).

    python3 scripts/recalibration_screenshot.py [--vamos target/release/vamos] [--out docs/img/recalibration.png]

Needs chromium + chromium-driver (Debian) and selenium (the Python `test` extra). Starts
`vamos serve` on a temporary data directory, stores the simulator's arm, the tiny test model
and a profile, calibrates it (one training episode, one held out), streams the pushed-robot
test episode with `vamos stream`, marks its alarm as a false alarm, starts a
recalibration from the nominal set, waits for its proposal, and screenshots the page
signed in as admin (the proposal with its plot and Apply button, the profile's nominal
set). Prints the proposal.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By

ROOT = Path(__file__).resolve().parents[1]
SIM = ROOT / "tests" / "fixtures" / "sim"
ADMIN, ROBOT = "screenshot-admin", "screenshot-robot"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--vamos", type=Path, default=ROOT / "target" / "release" / "vamos")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "recalibration.png")
    args = ap.parse_args()
    env = {k: v for k, v in os.environ.items() if not k.startswith("VAMOS_")}
    env.update(VAMOS_ADMIN_TOKEN=ADMIN, VAMOS_ROBOT_TOKEN=ROBOT, VAMOS_LOG__LEVEL="warn")
    grpc, rest = free_port(), free_port()
    base = f"http://127.0.0.1:{rest}"

    def call(method: str, path: str, body: bytes | None = None, ctype: str = "application/json") -> Any:
        req = urllib.request.Request(base + path, data=body, method=method,
                                     headers={"Authorization": f"Bearer {ADMIN}", "Content-Type": ctype})
        with urllib.request.urlopen(req, timeout=120) as r:
            text = r.read()
            return json.loads(text) if text else None

    def wait_job(job: int) -> Any:
        while (j := call("GET", f"/v1/jobs/{job}"))["state"] == "running":
            time.sleep(0.3)
        return j

    with tempfile.TemporaryDirectory() as tmp:
        server = subprocess.Popen([str(args.vamos), "serve", "--data-dir", f"{tmp}/data", "--grpc-addr",
                                   f"127.0.0.1:{grpc}", "--rest-addr", f"127.0.0.1:{rest}"], env=env)
        try:
            deadline = time.monotonic() + 60
            while True:
                try:
                    urllib.request.urlopen(base + "/readyz", timeout=2)
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.2)
            octets = "application/octet-stream"
            call("PUT", "/v1/robots/arm?format=urdf", (SIM / "robot" / "vamos_arm.urdf").read_bytes(), octets)
            call("PUT", "/v1/models/tiny", (ROOT / "tests" / "fixtures" / "model" / "tiny_trained.vamos").read_bytes(),
                 octets)
            camera = json.loads((SIM / "camera.json").read_text())
            call("PUT", "/v1/profiles/arm-store", json.dumps({
                "robot": "arm", "camera": camera, "model": {"name": "tiny"}, "flow_preset": "realtime",
                "pipeline": {"stride": 1, "frames": {"width": 160, "height": 120, "variant": "masked"}},
            }).encode())
            job = call("POST", "/v1/profiles/arm-store/calibrate", json.dumps({
                "episodes": [str(SIM / "train" / "train_0000.mcap")],
                "holdout": [str(SIM / "train" / "train_0001.mcap")], "alpha": 0.5}).encode())
            assert wait_job(job["job"])["state"] == "succeeded"
            subprocess.run([str(args.vamos), "stream", "--server", f"http://127.0.0.1:{grpc}", "--profile",
                            "arm-store", str(SIM / "test" / "test_0001_external_push.mcap")],
                           env=env, stdout=subprocess.DEVNULL, check=True)
            alarm = call("GET", "/v1/alarms")["alarms"][0]["id"]
            call("POST", f"/v1/alarms/{alarm}/false-alarm", b'{"note": "someone leaned on the robot"}')
            while not all(e["finished"] for e in call("GET", "/v1/profiles/arm-store/nominal")["episodes"]):
                time.sleep(0.2)
            job = wait_job(call("POST", "/v1/profiles/arm-store/recalibrate")["job"])
            print(json.dumps(job["proposal"], indent=1))
            options = webdriver.ChromeOptions()
            for a in ("--headless", "--no-sandbox", "--disable-gpu", "--window-size=1000,640",
                      "--disable-background-networking", "--disable-component-update", "--no-first-run"):
                options.add_argument(a)
            options.binary_location = "/usr/bin/chromium"
            driver = webdriver.Chrome(options=options, service=Service("/usr/bin/chromedriver"))
            try:
                driver.get(base + "/ui")
                driver.find_element(By.ID, "token").send_keys(ADMIN)
                driver.find_element(By.ID, "signin").click()
                deadline = time.monotonic() + 30
                while "Apply" not in driver.find_element(By.ID, "jobs").text:
                    assert time.monotonic() < deadline, "no proposal on the page"
                    time.sleep(0.2)
                args.out.parent.mkdir(parents=True, exist_ok=True)
                driver.save_screenshot(str(args.out))
                print(f"wrote {args.out}")
            finally:
                driver.quit()
        finally:
            server.terminate()
            server.wait()


if __name__ == "__main__":
    main()
