"""Regenerates the gRPC stubs of ``proto/vamos/v1`` into ``src/vamos/v1``.

    python clients/python/generate_stubs.py [OUT_DIR]

Needs grpcio-tools at the version pinned in the ``test`` extra of pyproject.toml (the
generated files name the generator's version; ``tests/test_client_stubs.py`` regenerates
them into a temporary folder and fails when they differ from the committed ones).

``monitor_pb2.py`` is post-processed (:func:`for_old_protobuf`) so that it imports with
protobuf >= 3.12, the ``python3-protobuf`` of Ubuntu 22.04 (ROS 2 Humble): protoc's
output refuses any runtime older than itself and builds its classes with a module
protobuf added in 3.20; ``vamos/v1/_protobuf_compat.py`` stands in for both.
"""

from __future__ import annotations

import re
import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
PROTO_ROOT = ROOT / "proto"
PROTOS = [PROTO_ROOT / "vamos" / "v1" / "monitor.proto"]
GENERATED = ("monitor_pb2.py", "monitor_pb2.pyi", "monitor_pb2_grpc.py")


#: The minimum protobuf runtime of the post-processed stubs (pyproject's floor).
PROTOBUF_FLOOR = "3.12"


def _replace_once(text: str, pattern: str, replacement: str) -> str:
    new, count = re.subn(pattern, replacement, text, flags=re.MULTILINE)
    if count != 1:
        raise RuntimeError(f"generate_stubs: expected one match of {pattern!r} in protoc's output, found {count}: "
                           "update for_old_protobuf() for this grpcio-tools")
    return new


def for_old_protobuf(source: str) -> str:
    """protoc's ``*_pb2.py`` made importable with protobuf >= :data:`PROTOBUF_FLOOR`: no
    runtime version check, and the builder calls through ``vamos.v1._protobuf_compat``."""
    source = _replace_once(source, r"^(# Protobuf Python Version: .*\n)",
                           r"\1# Post-processed by clients/python/generate_stubs.py: imports with protobuf >= "
                           + PROTOBUF_FLOOR + r" (vamos/v1/_protobuf_compat.py).\n")
    source = _replace_once(source, r"^from google\.protobuf import runtime_version as _runtime_version\n", "")
    source = _replace_once(source, r"^_runtime_version\.ValidateProtobufRuntimeVersion\(\n(?:    .*\n)*\)\n", "")
    source = _replace_once(source, r"^from google\.protobuf\.internal import builder as _builder$",
                           "from vamos.v1 import _protobuf_compat as _builder")
    return _replace_once(source, r"^DESCRIPTOR = _descriptor_pool\.Default\(\)\.AddSerializedFile\(",
                         "DESCRIPTOR = _builder.AddSerializedFile(")


def generate(out_dir: Path) -> list[Path]:
    """Writes the generated modules into ``out_dir`` (the ``vamos/v1`` package folder)."""
    from grpc_tools import protoc  # type: ignore[import-untyped]

    with tempfile.TemporaryDirectory() as tmp:
        rc = protoc.main([
            "grpc_tools.protoc",
            f"-I{PROTO_ROOT}",
            f"--python_out={tmp}",
            f"--pyi_out={tmp}",
            f"--grpc_python_out={tmp}",
            *(str(p) for p in PROTOS),
        ])
        if rc != 0:
            raise RuntimeError(f"grpc_tools.protoc failed with exit code {rc}")
        out_dir.mkdir(parents=True, exist_ok=True)
        written = []
        for name in GENERATED:
            target = out_dir / name
            source = Path(tmp) / "vamos" / "v1" / name
            if name.endswith("_pb2.py"):
                target.write_text(for_old_protobuf(source.read_text()))
            else:
                shutil.copyfile(source, target)
            written.append(target)
    return written


def main() -> int:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "src" / "vamos" / "v1"
    for path in generate(out):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
