"""One recording, many MCAP layouts, one result.

The MCAP format lets a writer choose how a file is laid out: chunked or not, chunk size and
compression (none, LZ4, zstd), with or without message indexes, chunk indexes, statistics,
summary offsets, repeated schemas and channels, CRCs, attachments and metadata, and
messages in or out of log-time order. The MCAP project's conformance suite is generated
by its own tool (not on a package registry); here the variants are written by the MCAP
project's Python writer (``mcap`` on PyPI) from one recorded episode, in the test set-up,
and ``vamos score`` must give every variant exactly the scores of the original.

Needs ``VAMOS_BIN``; skipped without it or without ``mcap``.
"""

from __future__ import annotations

import json
import os
import random
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

mcap_reader = pytest.importorskip("mcap.reader")
from mcap.writer import CompressionType, IndexType, Writer  # noqa: E402

from _server import SIM, vamos_bin  # noqa: E402

SOURCE = SIM / "test" / "test_0000.mcap"


@dataclass(frozen=True)
class Layout:
    """How one variant is written (the options of ``mcap.writer.Writer``, and extras)."""

    name: str
    options: dict[str, Any] = field(default_factory=dict)
    #: Attachments and metadata records between the messages.
    extras: bool = False
    #: Messages written out of log-time order (each shuffled within a window of this many).
    shuffle: int = 0


NO_SUMMARY = dict(index_types=IndexType.NONE, use_statistics=False, use_summary_offsets=False,
                  repeat_channels=False, repeat_schemas=False)
LAYOUTS = [
    Layout("default"),
    Layout("unchunked", dict(use_chunking=False)),
    Layout("unchunked-no-summary", dict(use_chunking=False, **NO_SUMMARY)),
    Layout("chunked-no-summary", dict(**NO_SUMMARY)),
    Layout("uncompressed", dict(compression=CompressionType.NONE)),
    Layout("lz4", dict(compression=CompressionType.LZ4)),
    Layout("small-chunks-zstd", dict(chunk_size=4096)),
    Layout("small-chunks-lz4", dict(chunk_size=4096, compression=CompressionType.LZ4)),
    Layout("small-chunks-no-index", dict(chunk_size=4096, index_types=IndexType.NONE)),
    Layout("chunk-index-only", dict(chunk_size=4096, index_types=IndexType.CHUNK)),
    Layout("message-index-only", dict(chunk_size=4096, index_types=IndexType.MESSAGE)),
    Layout("no-statistics", dict(use_statistics=False)),
    Layout("no-summary-offsets", dict(use_summary_offsets=False)),
    Layout("no-repeated-records", dict(repeat_channels=False, repeat_schemas=False)),
    Layout("no-crcs", dict(enable_crcs=False)),
    Layout("data-crcs", dict(enable_data_crcs=True)),
    Layout("attachments-and-metadata", dict(chunk_size=4096), extras=True),
    Layout("unchunked-attachments-and-metadata", dict(use_chunking=False), extras=True),
    Layout("out-of-order-in-chunks", dict(chunk_size=1 << 20), shuffle=8),
    Layout("out-of-order-small-chunks", dict(chunk_size=4096), shuffle=8),
    Layout("out-of-order-no-summary", dict(chunk_size=4096, **NO_SUMMARY), shuffle=8),
    Layout("out-of-order-unchunked", dict(use_chunking=False), shuffle=8),
]


def _records(path: Path) -> list[tuple[Any, Any, Any]]:
    with path.open("rb") as f:
        return list(mcap_reader.make_reader(f).iter_messages(log_time_order=True))


def _write(path: Path, layout: Layout, records: list[tuple[Any, Any, Any]]) -> None:
    order = list(range(len(records)))
    if layout.shuffle:
        rng = random.Random(20261206)
        for start in range(0, len(order), layout.shuffle):
            window = order[start:start + layout.shuffle]
            rng.shuffle(window)
            order[start:start + layout.shuffle] = window
    with path.open("wb") as f:
        w = Writer(f, **layout.options)
        w.start(profile="ros2", library="vamos test_mcap_layouts")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for n, i in enumerate(order):
            schema, channel, message = records[i]
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(
                    channel.topic, channel.message_encoding,
                    schemas.get(channel.schema_id, 0), dict(channel.metadata))
            w.add_message(channels[channel.id], message.log_time, message.data, message.publish_time,
                          message.sequence)
            if layout.extras and n % 10 == 0:
                w.add_attachment(message.log_time, message.log_time, f"note-{n}.txt", "text/plain",
                                 f"attachment {n}".encode())
                w.add_metadata(f"meta-{n}", {"n": str(n)})
        w.finish()


def test_every_mcap_layout_scores_as_the_original(tmp_path: Path) -> None:
    records = _records(SOURCE)
    assert len(records) > 50
    bags = tmp_path / "bags"
    bags.mkdir()
    (bags / "original.mcap").write_bytes(SOURCE.read_bytes())
    for layout in LAYOUTS:
        _write(bags / f"{layout.name}.mcap", layout, records)
    sizes = {p.stem: p.stat().st_size for p in bags.iterdir()}
    # The variants differ on disk (else the test would prove nothing).
    assert len(set(sizes.values())) >= len(LAYOUTS) // 2, sizes

    profile = tmp_path / "sim-arm.toml"
    profile.write_text(
        f'name = "sim-arm"\nrobot = "{SIM / "robot" / "vamos_arm.urdf"}"\ncamera = "{SIM / "camera.json"}"\n'
        'flow_preset = "realtime"\n[pipeline]\nstride = 1\n[pipeline.frames]\nwidth = 160\nheight = 120\n'
        'variant = "masked"\n')
    out = tmp_path / "scores"
    env = {k: v for k, v in os.environ.items() if not k.startswith("VAMOS_")}
    run = subprocess.run([str(vamos_bin()), "score", "--profile", str(profile), str(bags), "--out", str(out)],
                         capture_output=True, text=True, env=env, timeout=900)
    assert run.returncode == 0, run.stderr[-4000:]

    def scores(name: str) -> list[dict[str, Any]]:
        """The frames' values (without their timings, which vary from run to run)."""
        lines = (out / f"{name}.scores.jsonl").read_text().splitlines()
        return [{k: v for k, v in json.loads(line).items() if k != "timings"} for line in lines]

    reference = scores("original")
    assert len(reference) >= 20
    for layout in LAYOUTS:
        got = scores(layout.name)
        assert [g["stamp_ns"] for g in got] == [r["stamp_ns"] for r in reference], layout
        for g, r in zip(got, reference):
            assert g.keys() == r.keys(), layout.name
            for key, want in r.items():
                have = g[key]
                ok = have == pytest.approx(want, rel=1e-9, abs=1e-12) if isinstance(want, float) else have == want
                assert ok, (layout.name, g["stamp_ns"], key, have, want)
