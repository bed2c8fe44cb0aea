"""The wire codec: round trips of every message, and every malformed case named by a WireError."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from common.wire import messages as m
from common.wire.codec import MESSAGE_TYPES, decode, encode, error_reply, read_error_reply
from common.wire.schema import SCHEMA_VERSION, WireError, WireModel
from common.yaw import FftBackend, YawSettings
from tests.builders import JOB_SETTINGS, patch_job

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
names = st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_-", min_size=1, max_size=12)


def vec(n: int) -> st.SearchStrategy[np.ndarray]:
    return hnp.arrays(np.float64, (n,), elements=finite)


def frames() -> st.SearchStrategy[m.Frame]:
    return st.tuples(st.integers(1, 40), st.integers(1, 40)).flatmap(
        lambda hw: st.builds(
            m.Frame,
            uav=names,
            seq=st.integers(0, 2**40),
            stamp_s=finite,
            width=st.just(hw[1]),
            height=st.just(hw[0]),
            pixels=hnp.arrays(np.uint8, hw),
        )
    )


def jobs(cls: type[m.PatchJob]) -> st.SearchStrategy[m.PatchJob]:
    def build(n: int, k: int, s: int, data: st.DataObject) -> m.PatchJob:
        indices = np.array(
            data.draw(st.lists(st.integers(0, 500), min_size=n, max_size=n, unique=True)), np.int32
        )
        prev = indices[:k]
        return cls(
            stream=data.draw(names),
            seq=data.draw(st.integers(0, 10**6)),
            prev_seq=data.draw(st.integers(-1, 10**6)),
            settings=m.YawJobSettings.of(
                YawSettings(patch_size_px=32, fft_backend=FftBackend.OPENCV, pyramid_level=1)
            ),
            indices=indices,
            crops=data.draw(hnp.arrays(np.uint8, (n, s, s))),
            prev_indices=prev,
            prev_crops=data.draw(hnp.arrays(np.uint8, (k, s, s))),
            budget_s=data.draw(st.floats(0.001, 10.0)),
        )

    return st.integers(0, 6).flatmap(
        lambda n: st.integers(0, n).flatmap(
            lambda k: st.builds(build, st.just(n), st.just(k), st.integers(1, 8), st.data())
        )
    )


def results(cls: type[m.PatchResult]) -> st.SearchStrategy[m.PatchResult]:
    return st.integers(0, 6).flatmap(
        lambda n: st.builds(
            cls,
            stream=names,
            seq=st.integers(0, 10**6),
            prev_seq=st.integers(-1, 10**6),
            member=names,
            indices=st.just(np.arange(n, dtype=np.int32)),
            shift_px=hnp.arrays(np.float64, (n, 2), elements=finite),
            confidence=hnp.arrays(np.float64, (n,), elements=st.floats(0, 1e6)),
            peak=hnp.arrays(np.float64, (n,), elements=st.floats(0, 1)),
            valid=hnp.arrays(np.bool_, (n,)),
            compute_s=st.floats(0, 10),
            members=st.dictionaries(names, st.integers(0, 100), max_size=3),
            speeds=st.dictionaries(names, st.floats(0, 1e6), max_size=3),
        )
    )


MESSAGES = st.one_of(
    frames(),
    st.builds(
        m.ImuSample,
        uav=names,
        seq=st.integers(0, 10**9),
        stamp_s=finite,
        gyro_rad_s=vec(3),
        accel_m_s2=vec(3),
    ),
    st.builds(m.RangeSample, uav=names, stamp_s=finite, range_m=st.floats(1e-3, 1e3)),
    st.builds(
        m.YawEstimate,
        uav=names,
        seq=st.integers(0, 10**9),
        stamp_s=finite,
        delta_yaw_rad=finite,
        yaw_rad=finite,
        inlier_count=st.integers(0, 500),
        patch_count=st.integers(0, 500),
        confidence=finite,
        low_confidence=st.booleans(),
        method=names,
        timings_ms=st.dictionaries(names, finite, max_size=4),
        members=st.dictionaries(names, st.integers(0, 500), max_size=4),
    ),
    st.builds(
        m.AttitudeEstimate,
        uav=names,
        stamp_s=finite,
        q_world_body=vec(4),
        covariance=hnp.arrays(np.float64, (3, 3), elements=finite),
    ),
    st.builds(
        m.PoseEstimate,
        uav=names,
        stamp_s=finite,
        p_world_body_m=vec(3),
        q_world_body=vec(4),
        covariance=hnp.arrays(np.float64, (6, 6), elements=finite),
        source=st.sampled_from(["vo", "pf"]),
    ),
    jobs(m.PatchJob),
    jobs(m.BlockJob),
    results(m.PatchResult),
    results(m.BlockResult),
    st.builds(
        m.Stats,
        role=names,
        node=names,
        index=st.integers(0, 100),
        stamp_s=finite,
        uptime_s=st.floats(0, 1e6),
        counters=st.dictionaries(names, st.integers(0, 10**9), max_size=4),
        shares=st.dictionaries(names, st.floats(0, 1), max_size=4),
    ),
    st.builds(
        m.Health,
        role=names,
        node=names,
        index=st.integers(0, 9),
        ok=st.booleans(),
        uptime_s=st.floats(0, 1e6),
    ),
    st.builds(m.ErrorReply, kind=names, error=st.text(max_size=50)),
)


def assert_same(a: WireModel, b: WireModel) -> None:
    assert type(a) is type(b)
    for name in type(a).model_fields:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f")
        else:
            assert x == y, name


@settings(max_examples=150, deadline=None)
@given(MESSAGES)
def test_every_message_round_trips_exactly(message: WireModel) -> None:
    payload, attachment = encode(message)
    assert_same(decode(payload, attachment), message)
    assert_same(decode(payload, attachment, type(message)), message)


def test_every_message_type_of_the_key_table_is_registered() -> None:
    wanted = {
        "Frame", "ImuSample", "RangeSample", "YawEstimate", "AttitudeEstimate", "PoseEstimate",
        "BlockJob", "BlockResult", "PatchJob", "PatchResult", "Stats", "Health", "RigMessage",
    }  # fmt: skip
    assert wanted <= set(MESSAGE_TYPES)


def test_pixels_travel_raw_in_the_payload_not_in_the_header() -> None:
    pixels = np.arange(480 * 752, dtype=np.uint32).astype(np.uint8).reshape(480, 752)
    payload, header = encode(m.Frame(uav="a", seq=3, stamp_s=0.15, width=752, height=480, pixels=pixels))
    assert payload == pixels.tobytes()
    assert len(header) < 200
    decoded = decode(payload, header, m.Frame)
    assert (
        np.shares_memory(decoded.pixels, np.frombuffer(payload, np.uint8)) or decoded.pixels.base is not None
    )


def test_header_only_messages_decode_without_attachment() -> None:
    body = error_reply("busy", "queue full")
    assert read_error_reply(body) == "busy: queue full"
    assert read_error_reply(b"\xff\x00garbage").startswith("\ufffd")


def _frame() -> tuple[bytes, bytes]:
    return encode(m.Frame(uav="a", seq=1, stamp_s=0.0, width=4, height=3, pixels=np.zeros((3, 4), np.uint8)))


def _header(attachment: bytes) -> dict:
    return msgpack.unpackb(attachment)


def _pack(header: object) -> bytes:
    return msgpack.packb(header, use_bin_type=True)


def _with(change: Callable[[dict], object]) -> tuple[bytes, bytes]:
    payload, attachment = _frame()
    header = _header(attachment)
    change(header)
    return payload, _pack(header)


MALFORMED = {
    "truncated payload": lambda: (_frame()[0][:-1], _frame()[1]),
    "extra payload": lambda: (_frame()[0] + b"x", _frame()[1]),
    "truncated header": lambda: (_frame()[0], _frame()[1][:-3]),
    "garbage header": lambda: (b"", b"\xc1\xc1\xc1"),
    "header not a map": lambda: (b"", _pack([1, 2, 3])),
    "wrong version": lambda: _with(lambda h: h.update(v=99)),
    "unknown type": lambda: _with(lambda h: h.update(t="Nope")),
    "unknown field": lambda: _with(lambda h: h["f"].update(colour="red")),
    "unknown header key": lambda: _with(lambda h: h.update(x=1)),
    "missing field": lambda: _with(lambda h: h["f"].pop("seq")),
    "NaN stamp": lambda: _with(lambda h: h["f"].update(stamp_s=math.nan)),
    "negative seq": lambda: _with(lambda h: h["f"].update(seq=-4)),
    "shape mismatch": lambda: _with(lambda h: h["f"].update(width=5)),
    "nbytes mismatch": lambda: _with(lambda h: h["a"][0].__setitem__(3, 11)),
    "bad dtype": lambda: _with(lambda h: h["a"][0].__setitem__(1, "<f2")),
    "object dtype": lambda: _with(lambda h: h["a"][0].__setitem__(1, "|O")),
    "bad shape": lambda: _with(lambda h: h["a"][0].__setitem__(2, [-1, 4])),
    "unknown array": lambda: _with(lambda h: h["a"][0].__setitem__(0, "colour")),
    "array twice": lambda: _with(lambda h: h["f"].update(pixels=1)),
    "wrong type of field": lambda: _with(lambda h: h["f"].update(seq="one")),
    "no payload no attachment": lambda: (None, None),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_messages_raise_a_wire_error_naming_the_problem(case: str) -> None:
    payload, attachment = MALFORMED[case]()
    with pytest.raises(WireError) as info:
        decode(payload, attachment)
    assert str(info.value)


def test_nan_in_an_array_is_rejected() -> None:
    sample = m.ImuSample(uav="a", stamp_s=0.0, gyro_rad_s=np.zeros(3), accel_m_s2=np.zeros(3))
    payload, attachment = encode(sample)
    bad = np.frombuffer(payload, np.float64).copy()
    bad[1] = np.nan
    with pytest.raises(WireError, match="NaN"):
        decode(bad.tobytes(), attachment)


def test_expected_type_is_enforced_and_subclasses_are_distinct() -> None:
    payload, attachment = _frame()
    with pytest.raises(WireError, match="expected ImuSample"):
        decode(payload, attachment, m.ImuSample)
    job = patch_job(0, cls=m.BlockJob)
    with pytest.raises(WireError, match="expected PatchJob"):
        decode(*encode(job), m.PatchJob)


def test_job_consistency_is_checked() -> None:
    crops = np.zeros((2, 8, 8), np.uint8)
    with pytest.raises(ValueError, match="subset"):
        patch_job(indices=np.array([1, 2]), crops=crops, prev_indices=np.array([5]), prev_crops=crops[:1])
    with pytest.raises(ValueError, match="distinct"):
        patch_job(indices=np.array([1, 1]), crops=crops)


def test_a_transient_job_brings_the_previous_crops_of_all_its_patches_or_none() -> None:
    crops = np.zeros((2, 8, 8), np.uint8)
    indices = np.array([1, 2], np.int32)
    with pytest.raises(ValueError, match="transient"):
        patch_job(
            indices=indices, crops=crops, prev_indices=indices[:1], prev_crops=crops[:1], transient=True
        )
    for prev in (indices, indices[:0]):  # all of them (to a worker), none (a foreman holds them)
        job = patch_job(indices=indices, crops=crops, prev_indices=prev, prev_crops=crops[: prev.size],
                        transient=True)  # fmt: skip
        assert decode(*encode(job), m.PatchJob).transient
    assert not patch_job().transient  # a frame's first pass, the default


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=64), st.binary(max_size=64))
def test_random_bytes_never_escape_as_anything_but_wire_error(payload: bytes, attachment: bytes) -> None:
    with contextlib.suppress(WireError):
        decode(payload, attachment)


@settings(max_examples=200, deadline=None)
@given(MESSAGES, st.data())
def test_every_truncation_of_a_valid_message_is_a_wire_error(message: WireModel, data: st.DataObject) -> None:
    payload, attachment = encode(message)
    cut_header = data.draw(st.integers(0, len(attachment) - 1))
    with pytest.raises(WireError):
        decode(payload, attachment[:cut_header])
    if payload:
        cut = data.draw(st.integers(0, len(payload) - 1))
        with pytest.raises(WireError):
            decode(payload[:cut], attachment)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-3, 40), min_size=1, max_size=12))
def test_job_indices_are_accepted_iff_distinct_and_non_negative_in_any_order(values: list[int]) -> None:
    indices = np.array(values, np.int32)
    crops = np.zeros((indices.size, 4, 4), np.uint8)
    good = len(set(values)) == len(values) and min(values) >= 0
    payload, attachment = encode(
        patch_job(validate=False, indices=indices, crops=crops, prev_crops=crops[:0])
    )
    if good:
        assert np.array_equal(decode(payload, attachment, m.PatchJob).indices, indices)
    else:
        with pytest.raises(WireError, match="distinct non-negative"):
            decode(payload, attachment, m.PatchJob)


@pytest.mark.parametrize(
    ("field", "value"),
    [("yaw_rad", math.nan), ("confidence", math.inf), ("timings_ms", {"total": -math.inf})],
)
def test_nan_or_inf_in_scalar_and_dict_fields_is_a_wire_error(field: str, value: object) -> None:
    fields = {"uav": "a", "seq": 1, "stamp_s": 0.0, "delta_yaw_rad": 0.0, "yaw_rad": 0.0,
              "inlier_count": 0, "patch_count": 0, "confidence": 0.0, "low_confidence": True,
              "method": "none", field: value}  # fmt: skip
    header = msgpack.packb({"v": SCHEMA_VERSION, "t": "YawEstimate", "f": fields, "a": []})
    with pytest.raises(WireError, match=field):
        decode(b"", header, m.YawEstimate)


def test_nan_in_job_settings_is_a_wire_error() -> None:
    crops = np.zeros((1, 4, 4), np.uint8)
    settings = {**JOB_SETTINGS.model_dump(mode="json"), "peak_sigma_px": math.nan}
    job: m.PatchJob = patch_job(1, 4, validate=False, settings=settings, crops=crops, prev_crops=crops[:0])
    with pytest.raises(WireError, match="finite"):
        decode(*encode(job), m.PatchJob)


def test_a_service_message_names_its_member_as_its_liveliness_key_does() -> None:
    from common.wire import keys

    stats = m.Stats(role="worker", node="h1", index=2, uptime_s=1.0, stamp_s=0.0)
    health = m.Health(role="worker", node="h1", index=2, uptime_s=1.0, ok=True)
    alive = keys.parse_alive_key(keys.alive_key("worker", "h1", 2))
    assert stats.member == health.member == alive.name == "worker/h1/2"
