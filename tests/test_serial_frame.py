"""The serial frame format: encoding, CRC, and the streaming decoder's resync."""

from __future__ import annotations

import struct

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from rig.wire.serial_frame import (
    FRAME_SIZE,
    SYNC,
    Frame,
    FrameDecoder,
    crc16_ccitt_false,
    encode_frame,
)

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

_U32 = st.integers(0, 2**32 - 1)
_I32 = st.integers(-(2**31), 2**31 - 1)
_PAYLOAD = st.tuples(_U32, _I32, st.integers(0, 255))  # timestamp_us, counts, status


def _feed_in_chunks(decoder: FrameDecoder, stream: bytes, cuts: list[int]) -> list[Frame]:
    frames: list[Frame] = []
    edges = [0, *sorted(c % (len(stream) + 1) for c in cuts), len(stream)]
    for lo, hi in zip(edges, edges[1:]):
        frames += decoder.feed(stream[lo:hi])
    return frames


def _assert_bytes_accounted(decoder: FrameDecoder) -> None:
    s = decoder.stats
    whole = FRAME_SIZE * (s.frames_ok + s.duplicates + s.bad_version)
    assert s.bytes_in == whole + s.bytes_discarded + decoder.pending


def _flip(frame: bytes, bits: list[int]) -> bytes:
    out = bytearray(frame)
    for bit in bits:
        out[bit // 8] ^= 1 << (bit % 8)
    return bytes(out)


def test_crc_is_ccitt_false_check_value() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1


def test_encode_layout_matches_the_documented_table() -> None:
    raw = encode_frame(seq=65535, timestamp_us=4294967295, counts=-5, status=1)
    assert raw.hex(" ") == "a5 5a ff ff ff ff ff ff fb ff ff ff 01 01 66 7f"
    assert struct.unpack("<H", raw[14:])[0] == crc16_ccitt_false(raw[2:14])


def test_encode_wraps_seq_and_timestamp_and_rejects_bad_fields() -> None:
    (frame,) = FrameDecoder().feed(encode_frame(65536 + 3, 2**32 + 7, 500_000, 0))
    assert frame == Frame(seq=3, timestamp_us=7, counts=500_000, status=0)
    with pytest.raises(ValueError, match="counts"):
        encode_frame(0, 0, 2**31, 0)
    with pytest.raises(ValueError, match="status"):
        encode_frame(0, 0, 0, 256)


def test_gaps_count_across_the_uint16_wrap_and_duplicates_are_dropped() -> None:
    decoder = FrameDecoder()
    stream = b"".join(encode_frame(s, 0, 0) for s in (65534, 65535, 2, 2, 3))
    assert [f.seq for f in decoder.feed(stream)] == [65534, 65535, 2, 3]
    assert decoder.stats.seq_gaps == 2  # 0 and 1 are missing
    assert decoder.stats.duplicates == 1


def test_a_frame_of_another_version_is_counted_not_returned() -> None:
    body = struct.pack("<HIiBB", 1, 0, 0, 0, 2)
    foreign = SYNC + body + struct.pack("<H", crc16_ccitt_false(body))
    decoder = FrameDecoder()
    assert decoder.feed(foreign + encode_frame(2, 0, 0)) == [Frame(2, 0, 0, 0)]
    assert decoder.stats.bad_version == 1
    _assert_bytes_accounted(decoder)


def test_a_trailing_first_sync_byte_waits_for_its_partner() -> None:
    decoder = FrameDecoder()
    raw = encode_frame(9, 1, 2)
    assert decoder.feed(b"\x00\x01" + raw[:1]) == []
    assert decoder.pending == 1 and decoder.stats.bytes_discarded == 2
    assert decoder.feed(raw[1:]) == [Frame(9, 1, 2, 0)]


# garbage that holds no sync pattern and cannot complete one with a neighbour
_CLEAN_GARBAGE = st.binary(max_size=40).filter(
    lambda g: SYNC not in g and not g.startswith(SYNC[1:])
)


@st.composite
def _damaged_streams(draw: st.DrawFn) -> tuple[bytes, list[Frame], list[bool], list[int]]:
    """Frames with consecutive seq, clean garbage between, some with 1..3 flipped bits."""
    first_seq = draw(st.integers(0, 65535))
    payloads = draw(st.lists(_PAYLOAD, min_size=1, max_size=40))
    parts: list[bytes] = []
    frames: list[Frame] = []
    intact: list[bool] = []
    for i, (ts, counts, status) in enumerate(payloads):
        seq = (first_seq + i) % 65536
        raw = encode_frame(seq, ts, counts, status)
        bits = draw(st.lists(st.integers(0, 8 * FRAME_SIZE - 1), max_size=3, unique=True))
        # 1..3 bit errors in 16 bytes are always detected: CRC-CCITT has Hamming distance 4 here
        parts += [draw(_CLEAN_GARBAGE), _flip(raw, bits)]
        frames.append(Frame(seq, ts, counts, status))
        intact.append(not bits)
    cuts = draw(st.lists(st.integers(0, 10_000), max_size=12))
    return b"".join(parts), frames, intact, cuts


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(_damaged_streams())
def test_every_intact_frame_is_recovered_and_only_corrupted_ones_lost(
    case: tuple[bytes, list[Frame], list[bool], list[int]],
) -> None:
    stream, frames, intact, cuts = case
    decoder = FrameDecoder()
    got = _feed_in_chunks(decoder, stream, cuts)

    expected = [f for f, ok in zip(frames, intact) if ok]
    assert got == expected
    kept = [i for i, ok in enumerate(intact) if ok]
    lost_between = sum(not ok for ok in intact[kept[0] : kept[-1]]) if kept else 0
    assert decoder.stats.seq_gaps == lost_between
    assert decoder.stats.frames_ok == len(expected)
    assert decoder.stats.duplicates == 0
    _assert_bytes_accounted(decoder)


@st.composite
def _hostile_streams(draw: st.DrawFn) -> tuple[bytes, list[Frame], list[bool], list[int]]:
    """Any garbage (sync patterns included), bit flips, and truncated frames."""
    payloads = draw(st.lists(_PAYLOAD, min_size=1, max_size=30))
    garbage = st.binary(max_size=40) | st.just(SYNC) | st.just(SYNC + bytes(6))
    parts: list[bytes] = []
    frames: list[Frame] = []
    intact: list[bool] = []
    for seq, (ts, counts, status) in enumerate(payloads):
        raw = encode_frame(seq, ts, counts, status)
        fate = draw(st.sampled_from(["intact", "flip", "truncate"]))
        if fate == "flip":
            raw = _flip(raw, [draw(st.integers(0, 8 * FRAME_SIZE - 1))])
        elif fate == "truncate":
            raw = raw[: draw(st.integers(1, FRAME_SIZE - 1))]
        parts += [draw(garbage), raw]
        frames.append(Frame(seq, ts, counts, status))
        intact.append(fate == "intact")
    cuts = draw(st.lists(st.integers(0, 10_000), max_size=12))
    return b"".join(parts), frames, intact, cuts


@settings(max_examples=200, deadline=None)
@given(_hostile_streams())
# a sync pattern of garbage before a truncated frame: the window from it to the next
# intact frame's first bytes passed CRC with another format version, counted and not
# returned, and that frame was lost with it
@example((bytes.fromhex("a55a0000000000000000000000 01d894 a55a a55a010004340d00389530feef"
                        "a55a020000000000000000000001 3292".replace(" ", "")),
          [Frame(0, 0, 0, 0), Frame(1, 865284, -30370504, 239), Frame(2, 0, 0, 0)],
          [True, False, True], []))
def test_false_frames_are_rare_and_each_costs_at_most_one_intact_frame(
    case: tuple[bytes, list[Frame], list[bool], list[int]],
) -> None:
    stream, frames, intact, cuts = case
    decoder = FrameDecoder()
    got = _feed_in_chunks(decoder, stream, cuts)

    expected = [f for f, ok in zip(frames, intact) if ok]
    genuine = [f for f in got if f in expected]
    assert genuine == [f for f in expected if f in genuine]  # in order, no repeats
    # a false accept is a 16-byte window that passed CRC, returned or not: the streams
    # here hold no frame of another version and no repeated sequence number, so every
    # one counted as such is false too. It can swallow at most the one intact frame it
    # overlaps, and needs a 2**-16 CRC match to happen
    s = decoder.stats
    false_accepts = len(got) - len(genuine) + s.bad_version + s.duplicates
    assert len(expected) - len(genuine) <= false_accepts <= 1
    _assert_bytes_accounted(decoder)
