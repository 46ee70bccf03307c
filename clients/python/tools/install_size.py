"""What ``pip install`` of this package with some extras downloads and puts on disk,
without downloading it: pip resolves (``--dry-run --report``, for this interpreter and
platform), then each wheel's size and the unpacked size of its members are read from the
package index with HTTP range requests (the zip's central directory only).

    python clients/python/tools/install_size.py train      # the README's figures
    python clients/python/tools/install_size.py ""         # the core install

Prints the packages over 50 MB unpacked and the totals. Unpacked size leaves out the
``.pyc`` files pip compiles on install.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
import tempfile
import urllib.request
import zipfile
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1]


class _HttpFile(io.RawIOBase):
    """A seekable, read-only file over HTTP range requests."""

    def __init__(self, url: str) -> None:
        self.url, self.pos = url, 0
        with urllib.request.urlopen(urllib.request.Request(url, method="HEAD"), timeout=60) as r:
            self.size = int(r.headers["Content-Length"])

    def seekable(self) -> bool:
        return True

    def readable(self) -> bool:
        return True

    def tell(self) -> int:
        return self.pos

    def seek(self, offset: int, whence: int = 0) -> int:
        self.pos = offset if whence == 0 else self.pos + offset if whence == 1 else self.size + offset
        return self.pos

    def read(self, n: "int | None" = -1) -> bytes:
        if n is None or n < 0:
            n = self.size - self.pos
        if n == 0 or self.pos >= self.size:
            return b""
        end = min(self.size, self.pos + n) - 1
        req = urllib.request.Request(self.url, headers={"Range": f"bytes={self.pos}-{end}"})
        with urllib.request.urlopen(req, timeout=60) as r:
            data = bytes(r.read())
        self.pos += len(data)
        return data


def main() -> int:
    extras = sys.argv[1] if len(sys.argv) > 1 else "train"
    target = f"{PACKAGE}[{extras}]" if extras else str(PACKAGE)
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        subprocess.run([sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet",
                        "--report", str(report), target], check=True)
        resolved = json.loads(report.read_text())["install"]
    download = unpacked = 0
    for item in resolved:
        url = item["download_info"]["url"]
        if not url.endswith(".whl"):
            continue  # this package itself (a local folder)
        f = _HttpFile(url)
        with zipfile.ZipFile(f) as z:
            size = sum(info.file_size for info in z.infolist())
        download += f.size
        unpacked += size
        if size > 50e6:
            meta = item["metadata"]
            print(f"{meta['name']:26s} {meta['version']:12s} {f.size / 1e6:8.1f} MB download "
                  f"{size / 1e6:8.1f} MB unpacked")
    print(f"{len(resolved)} packages: {download / 1e6:.0f} MB download, {unpacked / 1e6:.0f} MB unpacked")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
