"""What `vamos bridge` adds to a frame's latency, measured on the wire
(docs/service-reference.md, "ROS 2: depth, and the bridge on the wire"; benches/README.md
"The ROS 2 bridge").

Cyclone DDS publishes the fixture bag's images, scaled up to WIDTH x HEIGHT rgb8 (camera
info scaled with them), and its joint states; each image waits for the previous one's
score (one frame in flight). Per frame: the time from the publisher's `write()` returning
(Cyclone's Python binding serialises a large image slowly, tens of ms, before it
returns; that is the test robot's cost, reported apart) to reading its
`vamos_msgs/FrameScore` back, and the server's own `latency_s` (the image reaching the
server to its score leaving it). Their difference is what DDS both ways, the bridge and
the gRPC hop add.

    VAMOS_BIN=target/release/vamos .venv/bin/python clients/ros2/dds_wire/bench_bridge.py \
        --width 640 --height 480 --passes 5
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import ros2_types as ros  # noqa: E402
from test_bridge_wire import EPISODE, Robot, Server, read_episode, stamp_ns, vamos_bin  # noqa: E402


def scaled(messages: list[tuple[str, Any]], factor: int) -> list[tuple[str, Any]]:
    """The bag's images `factor` times larger (pixels repeated) and its camera info to
    match; joint states as they are."""
    out = []
    for kind, m in messages:
        m = copy.copy(m)
        if kind == "image":
            px = np.asarray(m.data, dtype=np.uint8).reshape(m.height, m.step)[:, : 3 * m.width]
            px = px.reshape(m.height, m.width, 3).repeat(factor, axis=0).repeat(factor, axis=1)
            m.height, m.width = px.shape[0], px.shape[1]
            m.step = 3 * m.width
            m.data = px.tobytes()
        elif kind == "camera_info":
            m.height, m.width = m.height * factor, m.width * factor
            m.k = [v * factor if i in (0, 2, 4, 5) else v for i, v in enumerate(m.k)]
            m.p = [v * factor if i in (0, 2, 5, 6) else v for i, v in enumerate(m.p)]
        out.append((kind, m))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--width", type=int, default=640, help="image width (a multiple of 160), px")
    parser.add_argument("--height", type=int, default=480, help="image height (width * 3 / 4), px")
    parser.add_argument("--passes", type=int, default=5, help="passes over the bag's 30 images")
    args = parser.parse_args()
    factor = args.width // 160
    if factor * 160 != args.width or factor * 120 != args.height:
        parser.error("the size must be a multiple of the bag's 160x120")
    messages = scaled(read_episode(EPISODE), factor)
    bin = vamos_bin()
    with tempfile.TemporaryDirectory() as tmp:
        server = Server(bin, Path(tmp) / "server")
        try:
            robot = Robot(bin, Path(tmp), f"http://{server.grpc}", server.env)
            try:
                total, server_side, writes = [], [], []
                for _ in range(args.passes):
                    for kind, m in messages:
                        if kind != "image":
                            robot.write(kind, m)
                            continue
                        want = stamp_ns(m.header) + robot.offset_ns
                        before = time.monotonic()
                        robot.write(kind, m)
                        start = time.monotonic()
                        writes.append(start - before)
                        found: list[ros.FrameScore] = []
                        deadline = start + 5
                        while not found and time.monotonic() < deadline:
                            robot.drain()
                            found = [s for s in robot.scores if stamp_ns(s.header) == want]
                            if not found:
                                time.sleep(0.0005)
                        if found:
                            total.append(time.monotonic() - start)
                            server_side.append(found[0].latency_s)
                    robot.next_pass(messages)
                robot.stop()
            finally:
                robot.kill()
        finally:
            server.stop()
    n = len(total)
    added = sorted(t - s for t, s in zip(total, server_side))
    q = lambda xs, p: sorted(xs)[min(len(xs) - 1, int(p * (len(xs) - 1) + 0.5))]  # noqa: E731
    print(f"{args.width}x{args.height} rgb8, {n} frames scored of {args.passes * 30}")
    print(f"Cyclone's Python write() of an image: median {1e3 * statistics.median(writes):.1f} ms (not counted)")
    print(f"written -> FrameScore: median {1e3 * statistics.median(total):.1f} ms, p90 {1e3 * q(total, 0.9):.1f} ms")
    print(f"server latency_s:      median {1e3 * statistics.median(server_side):.1f} ms, "
          f"p90 {1e3 * q(server_side, 0.9):.1f} ms")
    print(f"added by DDS + bridge + gRPC: median {1e3 * statistics.median(added):.1f} ms, "
          f"p90 {1e3 * q(added, 0.9):.1f} ms")
    return 0 if n else 1


if __name__ == "__main__":
    raise SystemExit(main())
