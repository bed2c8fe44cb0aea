"""The image codecs of a :class:`~common.wire.messages.Frame` on the wire: ``mono8`` (raw), ``png`` and
``zstd`` (lossless: the decoded pixels are bit-identical) and ``jpeg`` (lossy, baseline grey, quality 1-100).
``zstd`` compresses each row's differences to its left neighbour (mod 256, PNG's Sub filter; the first
pixel of a row as it is) in one zstd frame with its checksum: on the simulated ground images that is a
quarter smaller than zstd of the raw pixels at a fraction of PNG's CPU. ``png`` is zlib level 1 with
Huffman coding only (faster and smaller than the default strategy on camera images, whose noise leaves
little for string matching).

:func:`encode` turns an ``(height, width)`` uint8 image into the bytes of one codec; :func:`decode` turns
them back and is the check at the boundary: it raises :class:`~common.wire.schema.WireError` naming what is
wrong, never a traceback, and never allocates more than the frame's declared ``height * width`` pixels for
the image. Before anything is decompressed, the size the stream states itself (PNG's IHDR chunk, JPEG's SOF
marker, zstd's frame content size when the frame states one) must be the declared size, and PNG and JPEG
must state one 8-bit grey channel (a colour image is refused, not converted); zstd decompresses with
``max_output_size = height * width`` and no trailing data; the decoded image must be exactly ``(height,
width)`` uint8. A PNG carries CRCs and a zstd frame must carry its checksum: their corrupt bytes are
refused. A JPEG has no checksum: a truncated one (no end-of-image marker) is refused, but bytes changed
inside its entropy-coded data decode to other pixels (libjpeg only warns).
"""

from __future__ import annotations

import struct
import typing
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt
import zstandard

from common.wire.schema import WireError

#: how a frame's pixels travel (``Frame.encoding``)
FrameEncoding = Literal["mono8", "jpeg", "png", "zstd"]
FRAME_ENCODINGS: tuple[str, ...] = typing.get_args(FrameEncoding)
#: the encodings whose decoded pixels are bit-identical to the sent ones
LOSSLESS: frozenset[str] = frozenset({"mono8", "png", "zstd"})
#: JPEG quality (libjpeg's 1-100 scale) when none is given
DEFAULT_JPEG_QUALITY = 90
#: libjpeg's quality scale
MIN_JPEG_QUALITY, MAX_JPEG_QUALITY = 1, 100
#: PNG's zlib level (0-9): 1 is libpng's fastest that still compresses (a camera compresses every frame)
PNG_LEVEL = 1
#: PNG's zlib strategy: Huffman coding only (``bench transport``: faster and smaller on camera images)
PNG_STRATEGY = cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY
#: zstd's level: 1 is its fastest regular level (a camera compresses every frame)
ZSTD_LEVEL = 1

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (SOF0..SOF15 without DHT 0xC4, JPG 0xC8 and DAC 0xCC)
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: JPEG markers without a length field (TEM, RST0..7, SOI, EOI)
_JPEG_STANDALONE = frozenset({0x01, *range(0xD0, 0xDA)})


def max_compressed_bytes(width: int, height: int) -> int:
    """The largest compressed frame accepted for a ``width x height`` image: twice the raw size plus 64 KiB
    (noise at JPEG quality 100 or in a PNG stays well under; anything larger is not an image of that size)."""
    return 2 * width * height + (1 << 16)


def encode(pixels: npt.NDArray[np.uint8], codec: str, quality: int = DEFAULT_JPEG_QUALITY) -> bytes:
    """The bytes of the ``(height, width)`` uint8 image ``pixels`` in ``codec`` (``quality``: jpeg only)."""
    if pixels.dtype != np.uint8 or pixels.ndim != 2 or 0 in pixels.shape:
        raise WireError(
            f"cannot encode a {pixels.dtype} image of shape {pixels.shape}: need (height, width) uint8"
        )
    image = np.ascontiguousarray(pixels)
    if codec == "mono8":
        return image.tobytes()
    if codec == "zstd":
        row_deltas = np.diff(image, axis=1, prepend=np.uint8(0))  # uint8: mod 256
        compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_content_size=True, write_checksum=True)
        return compressor.compress(row_deltas.tobytes())
    if codec == "png":
        params = [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL, cv2.IMWRITE_PNG_STRATEGY, PNG_STRATEGY]
    elif codec == "jpeg":
        if (
            isinstance(quality, bool)
            or not isinstance(quality, int)
            or not MIN_JPEG_QUALITY <= quality <= MAX_JPEG_QUALITY
        ):
            raise WireError(
                f"jpeg quality must be an integer in {MIN_JPEG_QUALITY}..{MAX_JPEG_QUALITY}, got {quality!r}"
            )
        params = [cv2.IMWRITE_JPEG_QUALITY, quality]
    else:
        raise WireError(f"unknown frame encoding {codec!r}; known: {', '.join(FRAME_ENCODINGS)}")
    ok, data = cv2.imencode(f".{codec}", image, params)
    if not ok:
        raise WireError(f"{codec}: the encoder refused a {image.shape} image")
    return bytes(data.tobytes())


def decode(data: bytes | memoryview, codec: str, width: int, height: int) -> npt.NDArray[np.uint8]:
    """The ``(height, width)`` uint8 image in ``data`` (``codec`` bytes), or a :class:`WireError` naming what
    is wrong (see the module's docstring: sizes are checked before anything is decompressed)."""
    if codec not in FRAME_ENCODINGS:
        raise WireError(f"unknown frame encoding {codec!r}; known: {', '.join(FRAME_ENCODINGS)}")
    for name, side in (("width", width), ("height", height)):
        if isinstance(side, bool) or not isinstance(side, int) or side <= 0:
            raise WireError(f"{codec} frame: {name} must be a positive integer, got {side!r}")
    data = bytes(data)
    size = width * height
    if codec == "mono8":
        if len(data) != size:
            raise WireError(f"mono8 frame: {len(data)} bytes for {width}x{height} (needs {size})")
        return np.frombuffer(data, np.uint8).reshape(height, width)
    if len(data) > max_compressed_bytes(width, height):
        raise WireError(
            f"{codec} frame: {len(data)} compressed bytes for a {width}x{height} image "
            f"(at most {max_compressed_bytes(width, height)})"
        )
    if codec == "zstd":
        return _decode_zstd(data, width, height)
    stated = _png_header(data) if codec == "png" else _jpeg_header(data)
    if stated != (width, height):
        raise WireError(f"{codec} frame states {stated[0]}x{stated[1]}, the frame header {width}x{height}")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise WireError(f"{codec} frame: corrupt data ({len(data)} bytes do not decode)")
    if image.dtype != np.uint8 or image.shape != (height, width):
        raise WireError(
            f"{codec} frame decoded to a {image.dtype} image of shape {image.shape}, "
            f"not ({height}, {width}) uint8"
        )
    return np.asarray(image, dtype=np.uint8)


def _decode_zstd(data: bytes, width: int, height: int) -> npt.NDArray[np.uint8]:
    size = width * height
    try:
        parameters = zstandard.get_frame_parameters(data)
    except zstandard.ZstdError as exc:
        raise WireError(f"zstd frame: not a zstd frame ({exc})") from None
    stated = parameters.content_size
    if not parameters.has_checksum:
        raise WireError("zstd frame: carries no checksum (corrupt bytes could not be told)")
    if stated != zstandard.CONTENTSIZE_UNKNOWN and stated != size:
        raise WireError(f"zstd frame states {stated} bytes, the frame header {width}x{height} = {size}")
    try:
        raw = zstandard.ZstdDecompressor().decompress(data, max_output_size=size, allow_extra_data=False)
    except zstandard.ZstdError as exc:
        raise WireError(
            f"zstd frame: corrupt or larger than {width}x{height} = {size} bytes ({exc})"
        ) from None
    if len(raw) != size:
        raise WireError(f"zstd frame: {len(raw)} bytes decompressed for {width}x{height} (needs {size})")
    row_deltas = np.frombuffer(raw, np.uint8).reshape(height, width)
    return np.cumsum(row_deltas, axis=1, dtype=np.uint8)  # uint8: mod 256


def _png_header(data: bytes) -> tuple[int, int]:
    """(width, height) stated by a PNG's IHDR chunk; an 8-bit grey image (colour type 0) or WireError."""
    if len(data) < 33 or data[:8] != _PNG_SIGNATURE or data[12:16] != b"IHDR":
        raise WireError("png frame: no PNG signature and IHDR chunk (corrupt or not a PNG)")
    width, height, depth, colour = struct.unpack(">IIBB", data[16:26])
    if depth != 8 or colour != 0:
        raise WireError(f"png frame: {depth}-bit colour type {colour}, not 8-bit grey (type 0)")
    return int(width), int(height)


def _jpeg_header(data: bytes) -> tuple[int, int]:
    """(width, height) stated by a JPEG's start-of-frame marker: 8-bit, one component (grey), else WireError.
    A JPEG without its end-of-image marker (a truncated one) is refused too."""
    if len(data) < 4 or data[:2] != b"\xff\xd8":
        raise WireError("jpeg frame: no start-of-image marker (corrupt or not a JPEG)")
    if data[-2:] != b"\xff\xd9":
        raise WireError("jpeg frame: no end-of-image marker (truncated)")
    at = 2
    while at + 4 <= len(data):
        if data[at] != 0xFF:
            raise WireError(f"jpeg frame: corrupt marker at byte {at}")
        marker = data[at + 1]
        if marker == 0xFF:  # fill byte
            at += 1
            continue
        if marker in _JPEG_STANDALONE:
            at += 2
            continue
        (length,) = struct.unpack(">H", data[at + 2 : at + 4])
        if length < 2 or at + 2 + length > len(data):
            raise WireError(f"jpeg frame: segment 0x{marker:02X} at byte {at} overruns the data")
        if marker in _JPEG_SOF:
            if length < 8:
                raise WireError("jpeg frame: start-of-frame segment too short")
            precision, height, width, components = struct.unpack(">BHHB", data[at + 4 : at + 10])
            if components != 1:
                raise WireError(f"jpeg frame: {components} colour components, not 1 (grey)")
            if precision != 8:
                raise WireError(f"jpeg frame: {precision}-bit samples, not 8-bit")
            if marker != 0xC0 and marker != 0xC1:
                raise WireError(f"jpeg frame: start-of-frame 0x{marker:02X}; only baseline/extended (C0, C1)")
            return int(width), int(height)
        if marker == 0xDA:  # start of scan before any frame header
            break
        at += 2 + length
    raise WireError("jpeg frame: no start-of-frame marker before the image data")
