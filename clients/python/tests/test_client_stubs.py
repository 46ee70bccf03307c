"""The committed gRPC stubs (src/vamos/v1) are what the proto generates today."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

pytest.importorskip("grpc_tools.protoc")

HERE = Path(__file__).resolve().parent
PACKAGE = HERE.parent


def _generator():
    spec = importlib.util.spec_from_file_location("generate_stubs", PACKAGE / "generate_stubs.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_committed_stubs_match_the_proto(tmp_path: Path) -> None:
    gen = _generator()
    written = gen.generate(tmp_path)
    assert [p.name for p in written] == list(gen.GENERATED)
    committed = PACKAGE / "src" / "vamos" / "v1"
    stale = [p.name for p in written if p.read_bytes() != (committed / p.name).read_bytes()]
    assert not stale, (f"{stale} differ from what proto/vamos/v1 generates: run "
                       "`python clients/python/generate_stubs.py` and commit the result")


def test_every_event_kind_has_a_name() -> None:
    from vamos.client._types import _EVENT_KINDS
    from vamos.v1 import monitor_pb2 as pb

    kinds = {v.number: v.name for v in pb.SessionEvent.Kind.DESCRIPTOR.values if v.number != 0}
    assert set(kinds) == set(_EVENT_KINDS)
    for number, name in kinds.items():
        assert name == "KIND_" + _EVENT_KINDS[number].upper()
