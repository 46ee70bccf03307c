"""Regenerates the gRPC stubs of ``proto/vamos/v1`` into ``src/vamos/v1``.

    python clients/python/generate_stubs.py [OUT_DIR]

Needs grpcio-tools at the version pinned in the ``test`` extra of pyproject.toml (the
generated files name the generator's version; ``tests/test_client_stubs.py`` regenerates
them into a temporary folder and fails when they differ from the committed ones).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
PROTO_ROOT = ROOT / "proto"
PROTOS = [PROTO_ROOT / "vamos" / "v1" / "monitor.proto"]
GENERATED = ("monitor_pb2.py", "monitor_pb2.pyi", "monitor_pb2_grpc.py")


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
            shutil.copyfile(Path(tmp) / "vamos" / "v1" / name, target)
            written.append(target)
    return written


def main() -> int:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "src" / "vamos" / "v1"
    for path in generate(out):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
