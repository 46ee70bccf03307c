"""Model bundles (``*.vamos``): write, read and verify them.

A bundle is a zip archive with exactly three members, ``manifest.json``, ``encoder.onnx`` and
``head.onnx`` (see ``docs/model-bundle.md``). This module only handles the container: the
manifest's ``members`` checksums, the member set and the format version. It needs nothing
beyond the standard library, so clients can inspect bundles without torch.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: ``format`` field of a model bundle manifest.
BUNDLE_FORMAT = "vamos-model"
#: Newest bundle ``format_version`` this package writes and reads.
BUNDLE_FORMAT_VERSION = 1
#: The ONNX members of a bundle, in archive order after ``manifest.json``.
ONNX_MEMBERS = ("encoder.onnx", "head.onnx")
#: Name of the manifest member.
MANIFEST_MEMBER = "manifest.json"

# Fixed zip timestamps make a bundle's bytes depend only on its content.
_ZIP_DATE_TIME = (1980, 1, 1, 0, 0, 0)


class BundleError(ValueError):
    """A bundle is malformed: wrong members, bad manifest, checksum mismatch."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


@dataclass(frozen=True)
class Bundle:
    """A bundle read from disk: its manifest and the bytes of its ONNX members."""

    manifest: dict[str, Any]
    encoder_onnx: bytes
    head_onnx: bytes


def sha256_hex(data: bytes) -> str:
    """Lowercase hex SHA-256 of ``data`` (the checksum format of ``members.*.sha256``)."""
    return hashlib.sha256(data).hexdigest()


def write_bundle(
    path: str | Path, manifest: dict[str, Any], encoder_onnx: bytes, head_onnx: bytes
) -> dict[str, Any]:
    """Write a bundle to ``path`` and return the manifest as written.

    ``manifest`` holds every field of the contract except ``members``, which is filled
    here from the ONNX bytes. Members are stored uncompressed, with fixed timestamps.
    The file is written to a temporary name and renamed, so a crash leaves no half bundle.
    """
    out = dict(manifest)
    out["members"] = {
        "encoder.onnx": {"sha256": sha256_hex(encoder_onnx)},
        "head.onnx": {"sha256": sha256_hex(head_onnx)},
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    manifest_bytes = (json.dumps(out, indent=2) + "\n").encode("utf-8")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as archive:
        for name, data in (
            (MANIFEST_MEMBER, manifest_bytes),
            ("encoder.onnx", encoder_onnx),
            ("head.onnx", head_onnx),
        ):
            info = zipfile.ZipInfo(name, date_time=_ZIP_DATE_TIME)
            info.compress_type = zipfile.ZIP_STORED
            info.external_attr = 0o644 << 16
            archive.writestr(info, data)
    tmp.replace(path)
    return out


def read_bundle(path: str | Path) -> Bundle:
    """Read and verify a bundle: member set, manifest format and version, checksums.

    Raises :class:`BundleError` on any mismatch.
    """
    path = Path(path)
    try:
        archive = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile) as err:
        raise BundleError(path, f"not a readable zip archive ({err})") from err
    with archive:
        names = sorted(archive.namelist())
        expected = sorted((MANIFEST_MEMBER, *ONNX_MEMBERS))
        if names != expected:
            raise BundleError(path, f"members are {names}, expected exactly {expected}")
        try:
            manifest = json.loads(archive.read(MANIFEST_MEMBER).decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as err:
            raise BundleError(path, f"manifest.json is not valid JSON ({err})") from err
        members = {name: archive.read(name) for name in ONNX_MEMBERS}
    if not isinstance(manifest, dict) or manifest.get("format") != BUNDLE_FORMAT:
        raise BundleError(path, f"manifest format is not {BUNDLE_FORMAT!r}")
    version = manifest.get("format_version")
    if not isinstance(version, int) or not 1 <= version <= BUNDLE_FORMAT_VERSION:
        raise BundleError(
            path, f"format_version {version!r} unsupported (this reader knows 1..{BUNDLE_FORMAT_VERSION})"
        )
    listed = manifest.get("members")
    if not isinstance(listed, dict) or sorted(listed) != sorted(ONNX_MEMBERS):
        raise BundleError(path, f"manifest members must list exactly {list(ONNX_MEMBERS)}")
    for name, data in members.items():
        entry = listed[name]
        want = entry.get("sha256") if isinstance(entry, dict) else None
        got = sha256_hex(data)
        if want != got:
            raise BundleError(path, f"{name}: sha256 is {got}, manifest says {want}")
    return Bundle(manifest=manifest, encoder_onnx=members["encoder.onnx"], head_onnx=members["head.onnx"])
