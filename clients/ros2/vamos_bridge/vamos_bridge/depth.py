"""Each camera image paired with the depth image nearest its stamp, without ROS or a
clock of its own (the caller passes the arrival time), so every rule is tested. The rules
and bounds are those of ``vamos bridge`` (crates/vamos-ros2/src/depth.rs) and of a
recorded bag's frames (``[episode] max_depth_gap_ms``):

- **Pairing.** A camera image takes the depth image whose header stamp is nearest its
  own if that is at most ``max_gap_ns`` away (the earlier of two as near), else it goes
  without one and the server places the scene at the profile's assumed depth.
- **Waiting.** Camera images wait in arrival order until one of: a depth image stamped at
  or after the image has arrived (depth images come in stamp order, so none nearer can
  follow), ``hold_s`` has passed since the image arrived (the bridge uses twice the gap),
  or more than :data:`MAX_WAITING_IMAGES` wait (the oldest goes). An image is never
  dropped for want of depth.
- **Depth images** are held sorted by stamp (a late one is put in its place), at most
  :data:`MAX_HELD_DEPTHS` (the oldest stamp goes first), and dropped once older than the
  gap before every image still to be paired and the newest one paired (the server
  refuses stamps that go back). One depth image may serve several camera images (a
  depth camera slower than the colour camera); one that arrives after its image went out
  is not sent again.
- **Encodings** are not checked here: the depth image goes as it came, and the server
  refuses an unusable one (not 16UC1/32FC1, another aspect ratio) for that frame with a
  message, scoring the frame at the assumed depth.
"""

from __future__ import annotations

import bisect
import collections
import time
from typing import Generic, Optional, TypeVar

#: Camera images that wait for their depth image at most; one more releases the oldest.
MAX_WAITING_IMAGES = 8
#: Depth images held at most; one more drops the oldest.
MAX_HELD_DEPTHS = 16

I = TypeVar("I")  # noqa: E741 - the camera image (anything the caller pairs)
D = TypeVar("D")  # the depth image


class DepthPairer(Generic[I, D]):
    """Camera images and depth images in; ``(image, depth or None)`` out, in the images'
    arrival order."""

    def __init__(self, max_gap_ns: int, hold_s: float) -> None:
        self.max_gap_ns = int(max_gap_ns)
        self.hold_s = float(hold_s)
        # (stamp_ns, image, arrival time).
        self._waiting: "collections.deque[tuple[int, I, float]]" = collections.deque()
        # Ascending stamps, and the depth image of each.
        self._stamps: list[int] = []
        self._depths: list[D] = []
        self._latest_depth_ns: Optional[int] = None
        self._last_paired_ns: Optional[int] = None

    def push_image(self, stamp_ns: int, image: I, now: float) -> list[tuple[I, Optional[D]]]:
        """A camera image arrived at ``now`` (seconds, monotonic): what goes out now."""
        self._waiting.append((int(stamp_ns), image, now))
        return self._release(now)

    def push_depth(self, stamp_ns: int, depth: D, now: float) -> list[tuple[I, Optional[D]]]:
        """A depth image stamped ``stamp_ns`` arrived at ``now``: what goes out now."""
        stamp_ns = int(stamp_ns)
        at = bisect.bisect_right(self._stamps, stamp_ns)
        self._stamps.insert(at, stamp_ns)
        self._depths.insert(at, depth)
        if len(self._stamps) > MAX_HELD_DEPTHS:
            del self._stamps[0], self._depths[0]
        self._latest_depth_ns = stamp_ns if self._latest_depth_ns is None else max(self._latest_depth_ns, stamp_ns)
        return self._release(now)

    def release_due(self, now: float) -> list[tuple[I, Optional[D]]]:
        """The images whose hold has ended by ``now``."""
        return self._release(now)

    def drain(self) -> list[tuple[I, Optional[D]]]:
        """Every waiting image, with the depth image it can have now (the bridge stops)."""
        return self._release(time.monotonic(), everything=True)

    def deadline(self) -> Optional[float]:
        """When the oldest waiting image's hold ends, if one waits."""
        return self._waiting[0][2] + self.hold_s if self._waiting else None

    def held(self) -> tuple[int, int]:
        """``(camera images waiting, depth images held)``."""
        return len(self._waiting), len(self._stamps)

    def _release(self, now: float, everything: bool = False) -> list[tuple[I, Optional[D]]]:
        out: list[tuple[I, Optional[D]]] = []
        while self._waiting:
            stamp, image, since = self._waiting[0]
            go = (everything or len(self._waiting) > MAX_WAITING_IMAGES
                  or (self._latest_depth_ns is not None and self._latest_depth_ns >= stamp)
                  or now - since >= self.hold_s)
            if not go:
                break
            self._waiting.popleft()
            out.append((image, self._nearest(stamp)))
            self._last_paired_ns = stamp if self._last_paired_ns is None else max(self._last_paired_ns, stamp)
        self._forget_old_depths()
        return out

    def _nearest(self, stamp_ns: int) -> Optional[D]:
        best: Optional[int] = None
        for i, t in enumerate(self._stamps):
            gap = abs(t - stamp_ns)
            if gap <= self.max_gap_ns and (best is None or gap < abs(self._stamps[best] - stamp_ns)):
                best = i
        return None if best is None else self._depths[best]

    def _forget_old_depths(self) -> None:
        stamps = [s for s, _, _ in self._waiting]
        if self._last_paired_ns is not None:
            stamps.append(self._last_paired_ns)
        if not stamps:
            return
        horizon = min(stamps) - self.max_gap_ns
        keep = bisect.bisect_left(self._stamps, horizon)
        del self._stamps[:keep], self._depths[:keep]
