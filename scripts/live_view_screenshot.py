#!/usr/bin/env python3
"""Screenshot of the live view during `vamos demo --serve` (docs/img/live_view.png).

    python3 scripts/live_view_screenshot.py [--vamos target/release/vamos] [--out docs/img/live_view.png]

Needs chromium + chromium-driver (Debian) and selenium (the Python `test` extra). Runs the
demo into a temporary folder, waits for the page's URL, opens it headless, picks the
session named by --session (default: the occluded-camera episode), waits until its
timeline, frame and alarms are drawn, saves the screenshot and stops the demo (SIGINT).
"""

from __future__ import annotations

import argparse
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By

ROOT = Path(__file__).resolve().parents[1]


def wait(what, check, timeout_s=120.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            v = check()
        except Exception:  # noqa: BLE001 - the DOM may be mid-update
            v = None
        if v:
            return v
        time.sleep(0.3)
    raise SystemExit(f"timed out waiting for {what}")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vamos", default=str(ROOT / "target" / "release" / "vamos"))
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "live_view.png"))
    ap.add_argument("--session", default="camera_occluded")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="vamos-live-shot-"))
    demo = subprocess.Popen([args.vamos, "demo", "--serve", "--quiet", "-o", str(work / "demo")],
                            stdout=subprocess.PIPE, text=True)
    url = None
    try:
        assert demo.stdout is not None
        for line in demo.stdout:
            sys.stdout.write(line)
            m = re.search(r"live view: (http://\S+/ui)", line)
            if m:
                url = m.group(1)
                break
        if url is None:
            raise SystemExit("the demo ended without printing the live view's URL")
        opts = webdriver.ChromeOptions()
        opts.binary_location = shutil.which("chromium") or "chromium"
        for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1500,1250"):
            opts.add_argument(a)
        d = webdriver.Chrome(service=Service(shutil.which("chromedriver") or "chromedriver"), options=opts)
        try:
            d.get(url)
            # Episodes replay in rounds: pick the session while it is live, and again in the
            # next round if it ended before its alarm showed.
            for _ in range(10):
                # Found and clicked in one script: the list is redrawn twice a second.
                wait("the session", lambda: d.execute_script(
                    "const r = [...document.querySelectorAll('#sessions tbody tr')]"
                    ".find((x) => (x.dataset.id || '').includes(arguments[0])); if (r) r.click(); return !!r;",
                    args.session))
                try:
                    wait("alarms", lambda: d.find_elements(By.CSS_SELECTOR, "#alarms li img"), 20)
                    break
                except SystemExit:
                    continue
            wait("the frame", lambda: int(d.find_element(By.ID, "overlay").get_attribute("data-frame")) > 0)
            time.sleep(2.0)
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            d.save_screenshot(args.out)
            print(f"screenshot: {args.out}")
        finally:
            d.quit()
    finally:
        demo.send_signal(signal.SIGINT)
        try:
            demo.wait(timeout=60)
        except subprocess.TimeoutExpired:
            demo.kill()
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
