"""The MVN stream parser and assembler (torchik/live/mvn.py): datagrams built byte by byte from the
specification's field table are read field for field; split messages are joined; duplicates,
late and malformed datagrams are counted and dropped, never raised."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from torchik.errors import InputError
from torchik.live.mvn import MVN_SEGMENTS, Assembler, parse_datagram
from torchik.live.sample import parse_url


def header(message_type: bytes, sample_counter: int, datagram_counter: int, items: int, time_code: int,
           character: int, payload: int, segments: int = 23, props: int = 0, fingers: int = 0) -> bytes:
    """The specification's header table, field by field, big-endian."""
    return (b"MXTP" + message_type + struct.pack(">I", sample_counter) + struct.pack(">B", datagram_counter)
            + struct.pack(">B", items) + struct.pack(">I", time_code) + struct.pack(">B", character)
            + struct.pack(">B", segments) + struct.pack(">B", props) + struct.pack(">B", fingers) + b"\0\0"
            + struct.pack(">H", payload))


def quaternion(k: int) -> tuple[float, ...]:
    q = np.array([1.0, 0.1 * k, -0.05 * k, 0.02], dtype=np.float32)
    return tuple(float(x) for x in (q / np.linalg.norm(q)).astype(np.float32))


def test_every_field_of_a_quaternion_pose_datagram_is_read_as_the_specification_lays_it_out():
    payload = b"".join(struct.pack(">i", k) + struct.pack(">3f", 0.1 * k, -0.2 * k, 1.5) + struct.pack(">4f", *quaternion(k))
                       for k in (1, 2, 3))
    data = header(b"02", 123456, 0x80 | 2, 3, 98765, 7, len(payload), 23, 1, 2) + payload
    d = parse_datagram(data)
    h = d.header
    assert (h.message_type, h.sample_counter, h.part, h.last, h.items, h.time_code, h.character) == \
        ("02", 123456, 2, True, 3, 98765, 7)
    assert (h.body_segments, h.props, h.finger_segments, h.payload_size) == (23, 1, 2, 96)
    assert d.items["id"].tolist() == [1, 2, 3]
    np.testing.assert_array_equal(d.items["position"][1], np.float32([0.2, -0.4, 1.5]))
    np.testing.assert_array_equal(d.items["quaternion"][2], np.float32(quaternion(3)))


def test_linear_and_angular_kinematics_datagrams_are_read_field_by_field():
    linear = struct.pack(">i", 5) + struct.pack(">9f", 1, 2, 3, 4, 5, 6, 7, 8, 9)
    angular = struct.pack(">i", 9) + struct.pack(">4f", *quaternion(1)) + struct.pack(">6f", 0.5, -0.5, 0.25, 10, 20, 30)
    d21 = parse_datagram(header(b"21", 1, 0x80, 1, 16, 0, len(linear)) + linear)
    d22 = parse_datagram(header(b"22", 1, 0x80, 1, 16, 0, len(angular)) + angular)
    assert d21.items["id"][0] == 5 and d22.items["id"][0] == 9
    np.testing.assert_array_equal(d21.items["position"][0], [1, 2, 3])
    np.testing.assert_array_equal(d21.items["velocity"][0], [4, 5, 6])
    np.testing.assert_array_equal(d21.items["acceleration"][0], [7, 8, 9])
    np.testing.assert_array_equal(d22.items["quaternion"][0], np.float32(quaternion(1)))
    np.testing.assert_array_equal(d22.items["angular_velocity"][0], [0.5, -0.5, 0.25])
    np.testing.assert_array_equal(d22.items["angular_acceleration"][0], [10, 20, 30])


def frame(counter: int, character: int = 0, split: int = 23) -> list[bytes]:
    """One frame as MVN sends it: type 21 for the pelvis, type 22 for every segment in datagrams
    of `split` segments, the last one flagged."""
    linear = struct.pack(">i", 1) + struct.pack(">9f", 0, 0, 1, 0.1, 0, 0, 0, 0, 0)
    out = [header(b"21", counter, 0x80, 1, counter * 10, character, len(linear)) + linear]
    chunks = [list(range(1, 24))[i:i + split] for i in range(0, 23, split)]
    for index, ids in enumerate(chunks):
        payload = b"".join(struct.pack(">i", i) + struct.pack(">4f", *quaternion(i + counter))
                           + struct.pack(">6f", 0.1 * i, 0, 0, 0, 0, 0) for i in ids)
        flag = 0x80 if index == len(chunks) - 1 else 0
        out.append(header(b"22", counter, index | flag, len(ids), counter * 10, character, len(payload)) + payload)
    return out


def feed(assembler: Assembler, datagrams) -> list:
    return [s for d in datagrams for s in assembler.add(d, 0.0)]


def test_split_messages_are_joined_into_one_sample_with_every_segment():
    assembler = Assembler()
    samples = feed(assembler, frame(10, split=5) + frame(11, split=5)[::-1] + frame(12, split=5))
    assert [s.frame for s in samples] == [10, 11, 12]
    s = samples[1]
    assert s.links == MVN_SEGMENTS and s.time == pytest.approx(0.11)
    np.testing.assert_allclose(s.quaternion[22], np.float32(quaternion(23 + 11)))
    np.testing.assert_allclose(s.angular_velocity[:, 0], np.float32(0.1 * np.arange(1, 24)))
    assert np.isnan(s.position[1:]).all() and s.position[0].tolist() == [0, 0, 1]
    assert assembler.stats.lost == 0 and assembler.stats.samples == 3


def test_duplicates_late_frames_and_gaps_are_counted_and_dropped():
    assembler = Assembler()
    stream = frame(1) + frame(2) + frame(2)[:1] + frame(4) + frame(3) + frame(5) + frame(5)[1:] + frame(6)
    samples = feed(assembler, stream)
    assert [s.frame for s in samples] == [1, 2, 4, 5, 6]
    st = assembler.stats
    assert (st.duplicates, st.late, st.lost) == (2, 2, 1)  # frame 3 arrived after 4: lost, its 2 datagrams late


def test_malformed_datagrams_are_counted_and_skipped_and_the_stream_goes_on():
    rng = np.random.default_rng(0)
    good = frame(1) + frame(2) + frame(3)
    bad = [good[1][:30], good[1][:10], b"XXTP" + good[1][4:], header(b"22", 2, 0x80, 200, 0, 0, 44) + good[1][24:68],
           bytes(rng.integers(0, 256, 300, dtype=np.uint8)), b"",
           header(b"22", 2, 0x80, 1, 0, 0, 44) + struct.pack(">i", 1) + struct.pack(">10f", *([math.nan] * 10)),
           header(b"22", 2, 0x80, 1, 0, 0, 44) + struct.pack(">i", 99) + struct.pack(">10f", 1, 0, 0, 0, 0, 0, 0, 0, 0, 0)]
    assembler = Assembler()
    samples = feed(assembler, good[:3] + bad + good[3:])
    assert [s.frame for s in samples] == [1, 2, 3]
    assert assembler.stats.malformed == len(bad)


def test_datagrams_parsed_as_one_batch_give_the_samples_and_counts_of_one_at_a_time():
    rng = np.random.default_rng(1)
    good = frame(1) + frame(2, split=5) + frame(2)[:1] + frame(4) + frame(3) + frame(5, character=2)
    bad = [good[1][:30], b"XXTP" + good[1][4:], bytes(rng.integers(0, 256, 300, dtype=np.uint8)),
           header(b"22", 6, 0x80, 1, 0, 0, 44) + struct.pack(">i", 99) + struct.pack(">10f", 1, 0, 0, 0, 0, 0, 0, 0, 0, 0)]
    stream = good[:4] + bad + good[4:] + frame(6) + frame(6, character=2)
    one, batch = Assembler(), Assembler()
    singly = feed(one, stream)
    together = batch.add_batch(stream, [0.0] * len(stream))
    assert [(s.character, s.frame) for s in together] == [(s.character, s.frame) for s in singly]
    for a, b in zip(singly, together):
        np.testing.assert_array_equal(a.quaternion, b.quaternion)
        np.testing.assert_array_equal(a.position, b.position)
    assert batch.stats == one.stats and one.stats.malformed == len(bad)


def test_stream_urls_are_checked_with_a_message_that_shows_valid_ones():
    assert parse_url("udp://:9763").port == 9763 and parse_url("lsl://mocap").name == "mocap"
    for text in ("http://x", "udp://host:99999", "lsl://", "udp://h:1/path"):
        with pytest.raises(InputError):
            parse_url(text)


def test_positions_streamed_in_cm_are_read_as_metres_when_told():
    metres = feed(Assembler(), frame(1) + frame(2))
    centimetres = feed(Assembler(position_scale=0.01), frame(1) + frame(2))
    np.testing.assert_allclose(centimetres[0].position[0], 0.01 * metres[0].position[0])
    np.testing.assert_allclose(centimetres[0].velocity[0], 0.01 * metres[0].velocity[0])
    np.testing.assert_array_equal(centimetres[0].quaternion, metres[0].quaternion)


def test_a_streamed_quaternion_gives_so3s_rotation_of_it_normalised_and_nan_where_it_is():
    import torch

    from torchik.live.mvn import rotations
    from torchik.method import so3

    q = np.random.default_rng(0).normal(size=(3, 5, 4)) * 0.7  # off unit length, as float32 streams leave them
    q[1, 2] = np.nan
    unit = q / np.linalg.norm(q, axis=-1, keepdims=True)
    expected = so3.quaternion_to_matrix(torch.from_numpy(unit)).numpy()
    np.testing.assert_allclose(rotations(q), expected, rtol=0, atol=1e-14)
    assert np.isnan(rotations(q)[1, 2]).all() and not np.isnan(rotations(q)[0]).any()
