"""A small PNG reader for the server's gray images (anomaly maps, alarm thumbnails),
standard library only: 8-bit grayscale, not interlaced, any of the five row filters.

The server writes these images with the ``image`` crate as 8-bit gray (``L8``); this
reads exactly that, so the client needs neither Pillow nor numpy to get the pixels. Any
other kind of PNG is refused with a :class:`ValueError` that says what it is.
"""

from __future__ import annotations

import struct
import zlib

SIGNATURE = b"\x89PNG\r\n\x1a\n"

#: Larger images are refused before their pixels are inflated (the server's maps and
#: thumbnails are a few hundred pixels wide at most).
MAX_PIXELS = 1 << 26


def decode_gray8(data: bytes) -> tuple[int, int, bytes]:
    """``(width, height, pixels)`` of an 8-bit grayscale PNG: ``pixels`` holds
    ``height`` rows of ``width`` bytes, top row first. Raises :class:`ValueError` for
    anything else (not a PNG, truncated, a bad checksum, another colour type or depth,
    interlaced)."""
    data = bytes(data)
    if not data.startswith(SIGNATURE):
        raise ValueError("not a PNG file (bad signature)")
    pos = len(SIGNATURE)
    header: "tuple[int, ...] | None" = None
    idat = bytearray()
    ended = False
    while pos < len(data):
        if pos + 8 > len(data):
            raise ValueError("PNG truncated in a chunk header")
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        crc = data[pos + 8 + length:pos + 12 + length]
        if len(body) != length or len(crc) != 4:
            raise ValueError(f"PNG truncated in chunk {kind!r}")
        if zlib.crc32(kind + body) != struct.unpack(">I", crc)[0]:
            raise ValueError(f"PNG chunk {kind!r} has a bad CRC")
        pos += 12 + length
        if kind == b"IHDR":
            if length != 13:
                raise ValueError("PNG header has the wrong length")
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        elif kind == b"IEND":
            ended = True
            break
    if header is None:
        raise ValueError("PNG without a header (IHDR)")
    if not ended:
        raise ValueError("PNG truncated (no IEND)")
    width, height, depth, colour, compression, filter_method, interlace = header
    if (depth, colour) != (8, 0):
        raise ValueError(f"PNG is not 8-bit grayscale (bit depth {depth}, colour type {colour})")
    if compression != 0 or filter_method != 0:
        raise ValueError("PNG uses an unknown compression or filter method")
    if interlace != 0:
        raise ValueError("interlaced PNGs are not read here")
    if width == 0 or height == 0 or width * height > MAX_PIXELS:
        raise ValueError(f"PNG size {width}x{height} is out of range")
    stride = width + 1  # one filter byte per row, one byte per pixel
    try:
        inflater = zlib.decompressobj()
        raw = inflater.decompress(bytes(idat), stride * height)
    except zlib.error as e:
        raise ValueError(f"PNG image data is corrupt: {e}") from None
    if len(raw) != stride * height:
        raise ValueError(f"PNG image data holds {len(raw)} bytes, expected {stride * height}")
    return width, height, _unfilter(raw, width, height)


def _unfilter(raw: bytes, width: int, height: int) -> bytes:
    """Undoes the row filters (PNG specification, section 9) for one byte per pixel."""
    out = bytearray(width * height)
    prior = bytearray(width)
    for y in range(height):
        f = raw[y * (width + 1)]
        row = bytearray(raw[y * (width + 1) + 1:(y + 1) * (width + 1)])
        if f == 0:
            pass
        elif f == 1:  # Sub
            for x in range(1, width):
                row[x] = (row[x] + row[x - 1]) & 0xFF
        elif f == 2:  # Up
            row = bytearray((a + b) & 0xFF for a, b in zip(row, prior, strict=True))
        elif f == 3:  # Average
            row[0] = (row[0] + (prior[0] >> 1)) & 0xFF
            for x in range(1, width):
                row[x] = (row[x] + ((row[x - 1] + prior[x]) >> 1)) & 0xFF
        elif f == 4:  # Paeth
            row[0] = (row[0] + prior[0]) & 0xFF
            for x in range(1, width):
                a, b, c = row[x - 1], prior[x], prior[x - 1]
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else b if pb <= pc else c
                row[x] = (row[x] + pred) & 0xFF
        else:
            raise ValueError(f"PNG row {y} has an unknown filter type {f}")
        out[y * width:(y + 1) * width] = row
        prior = row
    return bytes(out)
