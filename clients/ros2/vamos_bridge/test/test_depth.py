"""The pairing of camera images with depth images (no ROS, no clock: arrival times are
given). The same cases as crates/vamos-ros2/src/depth.rs's tests, so both bridges pair
alike."""

from __future__ import annotations

from typing import Optional

from vamos_bridge.depth import MAX_HELD_DEPTHS, MAX_WAITING_IMAGES, DepthPairer

MS = 1_000_000
GAP_NS, HOLD_S = 20 * MS, 0.040


def pairer() -> "DepthPairer[int, str]":
    # Images are their stamps, depth images a name.
    return DepthPairer(GAP_NS, HOLD_S)


def ms(t: float) -> float:
    return t / 1000


def test_each_image_takes_the_depth_image_nearest_its_stamp_within_the_gap() -> None:
    p = pairer()
    # Depth before the image: held; the image waits for a depth image at or after its
    # stamp, then takes the nearer of 995 and 1012.
    assert p.push_depth(995 * MS, "d995", 0.0) == []
    assert p.push_image(1000 * MS, 1000, ms(1)) == []
    assert p.push_depth(1012 * MS, "d1012", ms(2)) == [(1000, "d995")]
    # A depth image already at or after the next image's stamp: out at once.
    assert p.push_image(1010 * MS, 1010, ms(3)) == [(1010, "d1012")]
    # As near on both sides: the earlier.
    assert p.push_image(1022 * MS, 1022, ms(4)) == []
    assert p.push_depth(1032 * MS, "d1032", ms(5)) == [(1022, "d1012")]


def test_an_image_with_no_depth_image_within_the_gap_goes_without_one() -> None:
    p = pairer()
    p.push_depth(970 * MS, "d970", 0.0)
    assert p.push_image(1000 * MS, 1000, 0.0) == []
    # 21 ms after: past the gap, but at or after the stamp, so the image is decided.
    assert p.push_depth(1021 * MS, "d1021", ms(1)) == [(1000, None)]
    # No depth image at or after it: it waits for its hold, then goes without one.
    assert p.push_image(1042 * MS, 1042, ms(2)) == []
    assert p.release_due(ms(41)) == []
    assert p.release_due(ms(42)) == [(1042, None)]


def test_a_depth_image_exactly_the_gap_away_is_taken() -> None:
    p = pairer()
    p.push_image(1000 * MS, 1000, 0.0)
    assert p.push_depth(1020 * MS, "d1020", ms(1)) == [(1000, "d1020")]


def test_without_depth_images_an_image_goes_out_when_its_hold_ends() -> None:
    p = pairer()
    assert p.push_image(1, 1, 0.0) == []
    assert p.push_image(2, 2, 0.030) == []
    assert p.deadline() == HOLD_S
    assert p.release_due(0.039) == []
    assert p.release_due(0.040) == [(1, None)]
    assert p.deadline() == 0.030 + HOLD_S
    assert p.release_due(0.5) == [(2, None)]
    assert p.deadline() is None
    # A camera faster than the hold: never more than MAX_WAITING_IMAGES wait, the oldest
    # goes first, none is lost.
    out: list[tuple[int, Optional[str]]] = []
    for i in range(100):
        out += p.push_image(1000 + i, 1000 + i, 1.0)
        assert p.held()[0] <= MAX_WAITING_IMAGES
    assert len(out) == 100 - MAX_WAITING_IMAGES
    out += p.drain()
    assert out == [(1000 + i, None) for i in range(100)]


def test_depth_images_alone_are_held_in_a_bounded_window() -> None:
    p = pairer()
    for i in range(1000):
        assert p.push_depth(i * 33 * MS, f"d{i}", ms(i)) == []
        assert p.held()[1] <= MAX_HELD_DEPTHS
    assert p.held() == (0, MAX_HELD_DEPTHS)
    # The newest are kept: an image among them is paired at once, and the older ones
    # are dropped (older than the gap before the image).
    assert p.push_image(999 * 33 * MS - 5 * MS, 0, ms(1000)) == [(0, "d999")]
    assert p.held() == (0, 1)


def test_late_depth_images_and_out_of_order_stamps() -> None:
    p = pairer()
    # Depth images out of order: put in their place, the nearest still found.
    p.push_depth(1030 * MS, "d1030", 0.0)
    p.push_depth(990 * MS, "d990", 0.0)
    p.push_depth(1003 * MS, "d1003", 0.0)
    assert p.push_image(1000 * MS, 1000, 0.0) == [(1000, "d1003")]
    # Images out of order: an earlier stamp behind a later one waits behind it (arrival
    # order is kept) and still gets its own depth image.
    assert p.push_image(1100 * MS, 1100, ms(1)) == []
    assert p.push_image(1040 * MS, 1040, ms(2)) == []
    assert p.push_depth(1101 * MS, "d1101", ms(3)) == [(1100, "d1101"), (1040, "d1030")]
    # A depth image for an image that already went out is not sent again: older than the
    # gap before the newest image paired, it is dropped.
    assert p.push_depth(1045 * MS, "d1045", ms(4)) == []
    assert p.held() == (0, 1)
    assert p.push_image(1200 * MS, 1200, ms(5)) == []
    assert p.release_due(ms(45)) == [(1200, None)]
    assert p.held() == (0, 0)


def test_a_slow_depth_camera_serves_several_images() -> None:
    p = pairer()
    p.push_depth(1000 * MS, "d", 0.0)
    out = p.push_image(995 * MS, 995, 0.0) + p.push_image(1000 * MS, 1000, 0.0) + p.push_image(1010 * MS, 1010, 0.0)
    out += p.release_due(HOLD_S)
    assert out == [(995, "d"), (1000, "d"), (1010, "d")]


def test_drain_sends_what_waits_with_the_depth_it_can_have() -> None:
    p = pairer()
    p.push_depth(990 * MS, "d990", 0.0)
    p.push_image(1000 * MS, 1000, 0.0)
    p.push_image(1100 * MS, 1100, 0.0)
    assert p.drain() == [(1000, "d990"), (1100, None)]
    assert p.held()[0] == 0
