"""Compressed frames (common.wire.frame_codec and the wire codec's Frame): lossless codecs are bit-identical
for any image, JPEG's error is bounded, and every bad stream (truncated, corrupt, a lie about its size, a
bomb, colour) is a WireError naming what is wrong, checked before anything is decompressed."""

from __future__ import annotations

import functools
import struct
import zlib

import cv2
import msgpack
import numpy as np
import numpy.typing as npt
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from common.sim.flight import hover_flight
from common.wire import frame_codec
from common.wire.codec import decode, encode
from common.wire.messages import Frame
from common.wire.schema import WireError

LOSSLESS = sorted(frame_codec.LOSSLESS)
images = st.tuples(st.integers(1, 48), st.integers(1, 48)).flatmap(lambda hw: hnp.arrays(np.uint8, hw))


@functools.cache
def textured() -> npt.NDArray[np.uint8]:
    """A frame of paper A's simulated hover (752x480, ground texture with sensor noise)."""
    return hover_flight(seed=0, n_frames=2).frame(0)


def _frame(pixels: npt.NDArray[np.uint8], encoding: str, quality: int | None = None) -> Frame:
    height, width = pixels.shape
    fields = {"uav": "a", "seq": 1, "stamp_s": 0.0, "width": width, "height": height, "pixels": pixels}
    return Frame.model_validate({**fields, "encoding": encoding, "quality": quality})


# ------------------------------------------------------------------------------------------ round trips
@settings(max_examples=60, deadline=None)
@given(pixels=images, codec=st.sampled_from(LOSSLESS))
def test_lossless_codecs_are_bit_identical_for_any_image(pixels: npt.NDArray[np.uint8], codec: str) -> None:
    height, width = pixels.shape
    decoded = frame_codec.decode(frame_codec.encode(pixels, codec), codec, width, height)
    assert decoded.dtype == np.uint8 and decoded.shape == pixels.shape
    assert np.array_equal(decoded, pixels)


@settings(max_examples=40, deadline=None)
@given(pixels=images, codec=st.sampled_from(LOSSLESS))
def test_a_lossless_frame_travels_bit_identical_and_keeps_its_encoding(
    pixels: npt.NDArray[np.uint8], codec: str
) -> None:
    payload, attachment = encode(_frame(pixels, codec))
    received = decode(payload, attachment, Frame)
    assert received.encoding == codec
    assert np.array_equal(received.pixels, pixels)


def test_the_compressed_bytes_travel_as_one_array_instead_of_the_pixels() -> None:
    pixels = textured()
    payload, attachment = encode(_frame(pixels, "png"))
    header = msgpack.unpackb(attachment)
    assert header["f"]["encoding"] == "png"
    assert header["a"] == [[Frame.COMPRESSED_NAME, "|u1", [len(payload)], len(payload)]]
    assert payload == frame_codec.encode(pixels, "png")
    assert len(payload) < pixels.nbytes  # the hover's texture compresses


@pytest.mark.parametrize("quality", [1, 75, 90, 95, 100])
def test_jpeg_decodes_to_the_frame_size_with_a_bounded_error(quality: int) -> None:
    pixels = textured()
    data = frame_codec.encode(pixels, "jpeg", quality)
    decoded = frame_codec.decode(data, "jpeg", 752, 480)
    assert decoded.shape == (480, 752) and decoded.dtype == np.uint8
    error = np.abs(decoded.astype(np.int16) - pixels)
    if quality >= 90:
        assert error.mean() < 3.0 and error.max() < 40
    assert error.mean() < 20.0


def test_a_lower_jpeg_quality_sends_fewer_bytes_and_errs_more() -> None:
    pixels = textured()
    sizes, errors = [], []
    for quality in (95, 90, 75):
        data = frame_codec.encode(pixels, "jpeg", quality)
        sizes.append(len(data))
        errors.append(np.abs(frame_codec.decode(data, "jpeg", 752, 480).astype(np.int16) - pixels).mean())
    assert sizes[0] > sizes[1] > sizes[2] and errors[0] < errors[1] < errors[2]
    assert sizes[0] < pixels.nbytes


def test_a_jpeg_frame_travels_at_its_quality() -> None:
    pixels = textured()
    q75, q95 = (encode(_frame(pixels, "jpeg", q))[0] for q in (75, 95))
    default = encode(_frame(pixels, "jpeg"))[0]
    assert len(q75) < len(default) < len(q95)
    assert default == frame_codec.encode(pixels, "jpeg", frame_codec.DEFAULT_JPEG_QUALITY)
    received = decode(*encode(_frame(pixels, "jpeg", 75)), Frame)
    assert received.quality == 75 and received.pixels.shape == (480, 752)


# --------------------------------------------------------------------------------------------- bad input
def _png_with_ihdr(data: bytes, width: int, height: int, depth: int = 8, colour: int = 0) -> bytes:
    """``data`` (a PNG) with its IHDR stating another size or format (CRC recomputed: a consistent lie)."""
    body = b"IHDR" + struct.pack(">IIBB", width, height, depth, colour) + data[26:29]
    return data[:12] + body + struct.pack(">I", zlib.crc32(body)) + data[33:]


def _jpeg_with_size(data: bytes, width: int, height: int) -> bytes:
    at = data.index(b"\xff\xc0")
    return data[: at + 5] + struct.pack(">HH", height, width) + data[at + 9 :]


def _flip(data: bytes, at: int) -> bytes:
    changed = bytearray(data)
    changed[at] ^= 0xFF
    return bytes(changed)


def _bad_streams() -> dict[str, tuple[str, bytes, str]]:
    """name -> (codec, bytes for a 752x480 frame, what the error names)."""
    pixels = textured()
    png, jpeg, zstd = (frame_codec.encode(pixels, c) for c in ("png", "jpeg", "zstd"))
    big = zstandard.ZstdCompressor(write_checksum=True)
    unsized = zstandard.ZstdCompressor(write_checksum=True, write_content_size=False)
    colour = np.dstack([pixels, pixels // 2, pixels])
    return {
        "png truncated": ("png", png[: len(png) // 2], "corrupt"),
        "png corrupt": ("png", _flip(png, len(png) // 2), "corrupt"),
        "png not a png": ("png", b"GIF89a" + bytes(100), "not a PNG"),
        "png states another size": ("png", _png_with_ihdr(png, 8192, 8192), "states 8192x8192"),
        "png in colour": ("png", cv2.imencode(".png", colour)[1].tobytes(), "colour type 2"),
        "png 16-bit": ("png", cv2.imencode(".png", pixels.astype(np.uint16) * 257)[1].tobytes(), "16-bit"),
        "jpeg truncated": ("jpeg", jpeg[: len(jpeg) // 2], "truncated"),
        "jpeg not a jpeg": ("jpeg", b"\x00" * 100, "start-of-image"),
        "jpeg garbage markers": ("jpeg", b"\xff\xd8" + bytes(50) + b"\xff\xd9", "corrupt marker"),
        "jpeg states another size": ("jpeg", _jpeg_with_size(jpeg, 4000, 3000), "states 4000x3000"),
        "jpeg in colour": ("jpeg", cv2.imencode(".jpg", colour)[1].tobytes(), "3 colour components"),
        "jpeg progressive": (
            "jpeg",
            cv2.imencode(".jpg", pixels, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes(),
            "only baseline",
        ),
        "jpeg no frame header": (
            "jpeg",
            b"\xff\xd8\xff\xda\x00\x02" + bytes(10) + b"\xff\xd9",
            "no start-of-frame",
        ),
        "zstd truncated": ("zstd", zstd[:-10], "corrupt"),
        "zstd corrupt": ("zstd", _flip(zstd, len(zstd) // 2), "corrupt"),
        "zstd not zstd": ("zstd", b"hello" * 20, "not a zstd frame"),
        "zstd states more than the frame": (
            "zstd",
            big.compress(bytes(4 * 752 * 480)),
            "states 1443840 bytes",
        ),
        "zstd expands beyond the frame": (
            "zstd",
            unsized.compress(bytes(4 * 752 * 480)),
            "larger than 752x480",
        ),
        "zstd expands to less than the frame": ("zstd", unsized.compress(bytes(100)), "100 bytes"),
        "zstd without checksum": ("zstd", zstandard.ZstdCompressor().compress(pixels.tobytes()), "checksum"),
        "zstd trailing bytes": ("zstd", zstd + b"tail", "corrupt"),
        "more compressed bytes than any image": ("png", png + bytes(2 * 752 * 480), "compressed bytes"),
        "mono8 of the wrong size": ("mono8", bytes(100), "100 bytes"),
        "an unknown codec": ("webp", png, "unknown frame encoding"),
    }


BAD = _bad_streams()


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_stream_is_a_wire_error_naming_the_problem(case: str) -> None:
    codec, data, named = BAD[case]
    with pytest.raises(WireError, match=named):
        frame_codec.decode(data, codec, 752, 480)


#: the cases of a compressed frame (the wire refuses an unknown encoding and carries mono8 as pixels)
COMPRESSED_CASES = sorted(case for case, (codec, _, _) in BAD.items() if codec in ("png", "jpeg", "zstd"))


@pytest.mark.parametrize("case", COMPRESSED_CASES)
def test_a_bad_stream_in_a_frame_is_a_wire_error_at_the_boundary(case: str) -> None:
    codec, data, named = BAD[case]
    _, attachment = encode(_frame(textured(), codec))
    header = msgpack.unpackb(attachment)
    header["a"] = [[Frame.COMPRESSED_NAME, "|u1", [len(data)], len(data)]]
    with pytest.raises(WireError, match=named):
        decode(data, msgpack.packb(header), Frame)


def _compressed_header(change: dict[str, object]) -> tuple[bytes, bytes]:
    payload, attachment = encode(_frame(textured(), "png"))
    header = msgpack.unpackb(attachment)
    header["f"].update(change)
    return payload, msgpack.packb(header)


def test_a_frame_of_the_wrong_kind_of_array_is_refused() -> None:
    pixels = np.zeros((3, 4), np.uint8)
    raw, raw_header = encode(_frame(pixels, "mono8"))
    claims_png = msgpack.unpackb(raw_header)
    claims_png["f"]["encoding"] = "png"
    with pytest.raises(WireError, match="not pixels"):
        decode(raw, msgpack.packb(claims_png), Frame)
    payload, attachment = _compressed_header({"encoding": "mono8"})
    with pytest.raises(WireError, match="compressed bytes in a frame of encoding 'mono8'"):
        decode(payload, attachment, Frame)
    payload, attachment = _compressed_header({"encoding": "gif"})
    with pytest.raises(WireError, match="'gif'"):
        decode(payload, attachment, Frame)


def test_a_compressed_array_must_be_one_dimensional_bytes() -> None:
    payload, attachment = encode(_frame(textured(), "png"))
    header = msgpack.unpackb(attachment)
    header["a"][0][2] = [1, len(payload)]
    with pytest.raises(WireError, match="expected shape"):
        decode(payload, msgpack.packb(header), Frame)


@pytest.mark.parametrize("side", [0, 8193, -1, "752", True])
def test_the_declared_size_is_bounded_before_anything_is_decompressed(side: object) -> None:
    payload, attachment = _compressed_header({"width": side})
    with pytest.raises(WireError, match=r"Frame\.width"):
        decode(payload, attachment, Frame)


def test_a_declared_size_other_than_the_streams_is_refused() -> None:
    payload, attachment = _compressed_header({"width": 700})
    with pytest.raises(WireError, match="states 752x480, the frame header 700x480"):
        decode(payload, attachment, Frame)


def test_quality_belongs_to_jpeg_only_and_is_bounded() -> None:
    pixels = np.zeros((3, 4), np.uint8)
    for encoding, quality in (("png", 90), ("mono8", 50), ("jpeg", 0), ("jpeg", 101)):
        with pytest.raises(ValueError, match="quality"):
            _frame(pixels, encoding, quality)
    with pytest.raises(WireError, match="quality"):
        frame_codec.encode(pixels, "jpeg", 0)


def test_an_image_that_is_not_grey_bytes_is_not_encoded() -> None:
    with pytest.raises(WireError, match="need \\(height, width\\) uint8"):
        frame_codec.encode(np.zeros((3, 4, 3), np.uint8), "png")
    with pytest.raises(WireError, match="need \\(height, width\\) uint8"):
        frame_codec.encode(np.zeros((3, 4), np.uint16), "zstd")


def test_zstd_carries_each_rows_differences_to_its_left_neighbour() -> None:
    """The format other senders must write: row deltas mod 256 (PNG's Sub filter), one zstd frame."""
    pixels = np.array([[10, 5, 250], [0, 255, 1]], np.uint8)
    deltas = zstandard.ZstdDecompressor().decompress(frame_codec.encode(pixels, "zstd"))
    assert list(deltas) == [10, 251, 245, 0, 255, 2]


@functools.cache
def _small_streams() -> dict[str, bytes]:
    pixels = textured()[:60, :80].copy()
    return {codec: frame_codec.encode(pixels, codec) for codec in ("png", "jpeg", "zstd")}


@settings(max_examples=300, deadline=None)
@given(
    codec=st.sampled_from(["png", "jpeg", "zstd"]),
    changes=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), max_size=6),
    cut=st.integers(0, 10**6),
)
def test_changed_or_cut_bytes_decode_to_the_frame_size_or_a_wire_error(
    codec: str, changes: list[tuple[int, int]], cut: int
) -> None:
    """Never another exception (cv2.error, struct.error, ...): bytes changed anywhere (the headers too)
    and the stream cut anywhere."""
    data = bytearray(_small_streams()[codec])
    for at, value in changes:
        data[at % len(data)] = value
    data = data[: max(1, len(data) - cut % len(data))] if cut % 3 == 0 else data
    try:
        decoded = frame_codec.decode(bytes(data), codec, 80, 60)
    except WireError as exc:
        assert str(exc)
    else:
        assert decoded.shape == (60, 80) and decoded.dtype == np.uint8
