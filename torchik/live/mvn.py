"""The Xsens MVN real-time network stream: datagrams parsed, joined into one `Sample` per character
and frame (the receiver over UDP or TCP: `mvn_source.py`), and written (for `torchik replay`).

Format: Xsens Technologies, "MVN real-time network streaming protocol specification" (revisions
E to O, MVN Analyze/Animate 3.3 to 2022). Every datagram is a 24-byte big-endian header and a
payload of items:

| bytes | field |
|---|---|
| 6 | ID string: "MXTP" and the message type as two ASCII digits ("02", "21", "22", ...) |
| 4 | sample counter, u32: the frame |
| 1 | datagram counter, u8: the datagram's index within the frame's message; MSB set on the last |
| 1 | number of items, u8: segments (or points) in this datagram |
| 4 | time code, u32: ms since the start of the stream |
| 1 | character ID, u8 |
| 1 | number of body segments, u8 (23 for a full body) |
| 1 | number of props, u8 |
| 1 | number of finger tracking segments, u8 |
| 2 | reserved |
| 2 | size of the payload in bytes, u16 |

Items, per segment, big-endian (segment ID i32, then float32 values):

| type | item | bytes |
|---|---|---|
| 02 | quaternion pose: ID, position x y z, quaternion re i j k | 32 |
| 21 | linear segment kinematics: ID, position, velocity, acceleration (3 each) | 40 |
| 22 | angular segment kinematics: ID, quaternion re i j k, angular velocity, angular acceleration (3 each) | 44 |

Units, checked against the sources (revision N of the specification, 2018; the MVN user manual
MV0319P; Xsens' streaming sample code): the quaternion is (re, i, j, k) = (w, x, y, z), normalised,
segment to world (spec 2.5.3, 2.5.8, 2.7.3), all in MVN's Z-up, right-handed world frame. Angular
velocities are rad/s: Xsens' own sample receiver converts the type 22 values with
XsMath_rad2deg to print them. Positions are metres (velocities m/s): the user manual's network
streaming table says of the quaternion pose "position units are in meters", as does Xsens'
knowledge base ("Network Streamer in MVN"), and MVNX files, whose recordings replay as these
streams, are in metres. The specification's general section 2.5.6 says "The unit is cm" for every
pose type, which is true of the Euler type 01 made for MotionBuilder (a cm world); should a stream
show its base a hundred times too far, `MvnSource(position_scale=0.01)` (`torchik live
--mvn-position-unit cm`) reads it as cm. Segment IDs 1..23 are the body segments
in MVN's order (`MVN_SEGMENTS`, the names MVNX files and the `xsens_to_human` map use); props and
finger segments follow them and are not read. A large message is split over several datagrams,
each with its own item count and an increasing datagram counter. Over TCP the same datagrams
follow each other on the connection.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import numpy as np

from .sample import Sample, SourceStats

MVN_SEGMENTS = ("Pelvis", "L5", "L3", "T12", "T8", "Neck", "Head", "RightShoulder", "RightUpperArm",
                "RightForeArm", "RightHand", "LeftShoulder", "LeftUpperArm", "LeftForeArm", "LeftHand",
                "RightUpperLeg", "RightLowerLeg", "RightFoot", "RightToe", "LeftUpperLeg", "LeftLowerLeg",
                "LeftFoot", "LeftToe")
HEADER = struct.Struct(">6sIBBIBBBB2xH")  # the 24 bytes of the table above
MAGIC = b"MXTP"
LAST_DATAGRAM = 0x80
ITEMS = {  # message type -> one item's fields, big-endian
    "02": np.dtype([("id", ">i4"), ("position", ">f4", 3), ("quaternion", ">f4", 4)]),
    "21": np.dtype([("id", ">i4"), ("position", ">f4", 3), ("velocity", ">f4", 3), ("acceleration", ">f4", 3)]),
    "22": np.dtype([("id", ">i4"), ("quaternion", ">f4", 4), ("angular_velocity", ">f4", 3),
                    ("angular_acceleration", ">f4", 3)]),
}
COLUMNS = {kind: {name: slice(where[1] // 4, where[1] // 4 + (item[name].shape or (1,))[0])
                  for name, where in (item.fields or {}).items() if name != "id"}
           for kind, item in ITEMS.items()}  # per message type, each field's 4-byte columns in an item
MAX_PENDING = 8  # frames of a character held while their datagrams arrive; older ones are given up


class MalformedDatagram(ValueError):
    """A datagram the parser refuses: short, a wrong header, counts that do not add up, bad values."""


class UnsupportedMessage(ValueError):
    """A well-formed MVN datagram of a message type torchik does not read (joint angles, meta data, ...)."""


class Header(NamedTuple):
    message_type: str
    sample_counter: int
    datagram_counter: int
    items: int
    time_code: int
    character: int
    body_segments: int
    props: int
    finger_segments: int
    payload_size: int

    @property
    def part(self) -> int:
        """The datagram's index within its frame's message."""
        return self.datagram_counter & ~LAST_DATAGRAM

    @property
    def last(self) -> bool:
        return bool(self.datagram_counter & LAST_DATAGRAM)


class Datagram(NamedTuple):
    """A datagram's header and items: as sent (structured, big-endian: ITEMS[header.message_type]),
    their values [items, 4-byte columns] as native float32 (COLUMNS says which columns are which
    field; the ID column's floats are meaningless) and their segment rows (ID - 1) [items]."""

    header: Header
    items: np.ndarray
    values: np.ndarray
    rows: np.ndarray


def parse_header(data: bytes) -> Header:
    if len(data) < HEADER.size:
        raise MalformedDatagram(f"short: {len(data)} bytes, a header alone is {HEADER.size}")
    ident, *fields = HEADER.unpack_from(data)
    if ident[:4] != MAGIC or not ident[4:].isdigit():
        raise MalformedDatagram(f"wrong ID string {ident!r}; expected MXTP and two digits")
    return Header(ident[4:].decode(), *fields)


def parse_datagram(data: bytes) -> Datagram:
    """One datagram's header and items. MalformedDatagram saying what is wrong; UnsupportedMessage
    for a message type other than 02, 21 and 22."""
    parsed = parse_datagrams([data])[0]
    if isinstance(parsed, ValueError):
        raise parsed
    return parsed


def parse_datagrams(datas: Sequence[bytes]) -> list[Datagram | ValueError]:
    """Each datagram parsed (as `parse_datagram`), or the MalformedDatagram or UnsupportedMessage
    that refuses it. The items of all the datagrams of a message type are converted and checked
    together: a few numpy calls per batch, not per datagram (the receiver reads some 20,000
    datagrams a second from 64 characters)."""
    out: list = [None] * len(datas)
    groups: dict[str, list[tuple[int, Header]]] = {}
    for i, data in enumerate(datas):
        try:
            header = _checked_header(data)
        except ValueError as error:
            out[i] = error
            continue
        groups.setdefault(header.message_type, []).append((i, header))
    for message_type, members in groups.items():
        _parse_items(datas, members, message_type, out)
    return out


def _checked_header(data: bytes) -> Header:
    header = parse_header(data)
    item = ITEMS.get(header.message_type)
    if item is None:
        raise UnsupportedMessage(f"message type {header.message_type}")
    payload = len(data) - HEADER.size
    if header.payload_size not in (0, payload):  # revisions before MVN 2019 leave it 0
        raise MalformedDatagram(f"payload size field {header.payload_size}, payload {payload} bytes")
    if header.items * item.itemsize != payload:
        raise MalformedDatagram(f"{header.items} items of {item.itemsize} bytes in a payload of {payload}")
    return header


def _parse_items(datas: Sequence[bytes], members: list[tuple[int, Header]], message_type: str, out: list) -> None:
    """The datagrams `members` (index in datas, header: all of `message_type`, headers checked)
    parsed into `out` at their indices."""
    item = ITEMS[message_type]
    width = item.itemsize // 4
    headers = [h for _, h in members]
    payload = b"".join(memoryview(datas[i])[HEADER.size:] for i, _ in members)
    items = np.frombuffer(payload, item)
    # every value of every item at once, in native types (numpy is several times slower on
    # big-endian, strided data); the IDs' bytes read as floats are denormals, finite: one check
    raw = np.frombuffer(payload, ">f4").reshape(-1, width)
    values = raw.astype(np.float32)
    rows = raw[:, 0].view(">i4").astype(np.int64) - 1
    counts = np.fromiter((h.items for h in headers), np.int64, len(headers))
    limits = np.fromiter((h.body_segments + h.props + h.finger_segments for h in headers), np.int64, len(headers))
    bounds = np.concatenate(([0], np.cumsum(counts)))
    faults = ~np.isfinite(values).all(1) | (rows < 0) | (rows >= np.repeat(limits, counts))
    columns = COLUMNS[message_type].get("quaternion")
    if columns is not None:
        q = values[:, columns]
        # |q|^2 - 1 = 2 (|q| - 1) to first order: |q| within 1e-3 of 1
        faults |= np.abs(np.einsum("ij,ij->i", q, q) - 1.0) > 2e-3
    faulty = np.concatenate(([0], np.cumsum(faults)))
    for k, (i, header) in enumerate(members):
        a, b = int(bounds[k]), int(bounds[k + 1])
        datagram = Datagram(header, items[a:b], values[a:b], rows[a:b])
        out[i] = datagram if faulty[b] == faulty[a] else _fault(datagram, columns)


def _fault(datagram: Datagram, quaternion_columns: slice | None) -> MalformedDatagram:
    """What is wrong with a datagram whose items failed a check."""
    values, rows, header = datagram.values, datagram.rows, datagram.header
    if not np.isfinite(values).all():
        return MalformedDatagram("non-finite values (or a negative segment ID)")
    limit = header.body_segments + header.props + header.finger_segments
    low, high = int(rows.min()) + 1, int(rows.max()) + 1
    if low < 1 or high > limit:
        return MalformedDatagram(f"segment IDs {low}..{high} outside 1..{limit}")
    assert quaternion_columns is not None  # the one check left
    q = values[:, quaternion_columns]
    return MalformedDatagram(f"quaternion of norm {np.sqrt(np.einsum('ij,ij->i', q, q)).max():.4g}")


def encode_datagrams(message_type: str, sample_counter: int, time_code: int, character: int, ids: np.ndarray,
                     columns: dict[str, np.ndarray], body_segments: int = 23, max_bytes: int = 1472) -> list[bytes]:
    """One frame's message as datagrams of at most `max_bytes` (a UDP payload on Ethernet), for
    `torchik replay`. ids [n]; columns: the type's fields (ITEMS) as [n,k] arrays, cast to float32."""
    payloads = encode_payloads(message_type, ids, columns, max_bytes)
    return framed(message_type, payloads, sample_counter, time_code, character, body_segments)


def encode_payloads(message_type: str, ids: np.ndarray, columns: dict[str, np.ndarray],
                    max_bytes: int = 1472) -> list[bytes]:
    """The payloads (items) of the datagrams of `encode_datagrams`, without their headers."""
    item = ITEMS[message_type]
    items = np.zeros(len(ids), item)
    items["id"] = ids
    for name in (item.names or ())[1:]:
        items[name] = columns.get(name, 0.0)
    per_datagram = max(1, (max_bytes - HEADER.size) // item.itemsize)
    chunks = [items[i:i + per_datagram] for i in range(0, len(items), per_datagram)] or [items]
    return [chunk.tobytes() for chunk in chunks]


def framed(message_type: str, payloads: Sequence[bytes], sample_counter: int, time_code: int, character: int,
           body_segments: int = 23) -> list[bytes]:
    """Each payload of a frame's message behind its header: a replay encodes a recording's frame
    once (`encode_payloads`) and sends it as any character's frame."""
    ident, size, last = MAGIC + message_type.encode(), ITEMS[message_type].itemsize, len(payloads) - 1
    return [HEADER.pack(ident, sample_counter & 0xFFFFFFFF, k | (LAST_DATAGRAM if k == last else 0), len(payload) // size,
                        time_code & 0xFFFFFFFF, character, body_segments, 0, 0, len(payload)) + payload
            for k, payload in enumerate(payloads)]


@dataclass
class _Frame:
    """A frame's datagrams as they arrive: per message type, the datagrams by their index."""

    time_code: int
    body_segments: int
    parts: dict[str, dict[int, Datagram]] = field(default_factory=dict)
    last: dict[str, int] = field(default_factory=dict)

    def complete(self, types) -> bool:
        return all(t in self.last and len(self.parts[t]) == self.last[t] + 1 for t in types)


@dataclass
class _Character:
    newest: int | None = None  # the frame last delivered
    pending: dict[int, _Frame] = field(default_factory=dict)
    types: set[str] = field(default_factory=set)  # the message types a complete frame holds
    settled: bool = False  # types known: a datagram of a later frame has arrived


class Assembler:
    """Datagrams in, complete samples out: one per (character, sample counter), from every message
    type the stream carries (learnt from its first frame), split datagrams joined. Duplicates,
    late (reordered) datagrams and malformed ones are counted in `stats` and dropped.
    position_scale: metres per unit of the stream's positions (see the module docstring)."""

    def __init__(self, position_scale: float = 1.0) -> None:
        self.stats = SourceStats()
        self.position_scale = position_scale
        self._characters: dict[int, _Character] = {}

    def add(self, data: bytes, arrival: float) -> list[Sample]:
        """The samples that `data` completes (usually none or one)."""
        return self.add_batch([data], [arrival])

    def add_batch(self, datas: Sequence[bytes], arrivals: Sequence[float]) -> list[Sample]:
        """The samples that the datagrams `datas`, in the order they came (each at its arrival
        time), complete: as many `add` calls, with the items parsed in one batch."""
        self.stats.datagrams += len(datas)
        out: list[Sample] = []
        for datagram, arrival in zip(parse_datagrams(datas), arrivals):
            if isinstance(datagram, Datagram):
                out += self._assemble(datagram, arrival)
            elif isinstance(datagram, UnsupportedMessage):
                self.stats.ignored += 1
            else:
                self.stats.malformed += 1
        return out

    def _assemble(self, datagram: Datagram, arrival: float) -> list[Sample]:
        h = datagram.header
        c = self._characters.setdefault(h.character, _Character())
        counter = h.sample_counter
        if c.newest is not None and counter <= c.newest:
            if counter == c.newest:
                self.stats.duplicates += 1
            else:
                self.stats.late += 1
            return []
        frame = c.pending.setdefault(counter, _Frame(h.time_code, h.body_segments))
        parts = frame.parts.setdefault(h.message_type, {})
        if h.part in parts:
            self.stats.duplicates += 1
            return []
        parts[h.part] = datagram
        if h.last:
            frame.last[h.message_type] = h.part
        c.types.add(h.message_type)
        if not c.settled and len(c.pending) > 1:
            c.settled = True
        if len(c.pending) > MAX_PENDING:
            self._give_up(c, min(c.pending))
        return self._deliver(h.character, c, arrival) if c.settled else []

    def _give_up(self, c: _Character, counter: int) -> None:
        del c.pending[counter]
        self.stats.incomplete += 1

    def _deliver(self, character: int, c: _Character, arrival: float) -> list[Sample]:
        """The pending frames that are complete, oldest first; the incomplete ones before them given up."""
        out = []
        for counter in sorted(c.pending):
            frame = c.pending[counter]
            if not frame.complete(c.types):
                continue
            for older in [k for k in c.pending if k < counter]:
                self._give_up(c, older)
            del c.pending[counter]
            if c.newest is not None:
                self.stats.lost += counter - c.newest - 1
            c.newest = counter
            self.stats.samples += 1
            out.append(_sample(character, counter, frame, arrival, self.position_scale))
        return out


SAMPLE_FIELDS = {"02": ("position", "quaternion"), "21": ("position", "velocity"),
                 "22": ("quaternion", "angular_velocity")}  # what a Sample takes of each message type


def _sample(character: int, counter: int, frame: _Frame, arrival: float, position_scale: float = 1.0) -> Sample:
    """A complete frame as a Sample of the body segments (props and fingers left out): each message
    type's items converted whole when they are the body's segments in order (MVN's usual message),
    else scattered by segment ID into rows of NaN; the fields are column views of these tables."""
    n = frame.body_segments
    names = MVN_SEGMENTS if n == len(MVN_SEGMENTS) else tuple(f"segment{i}" for i in range(1, n + 1))
    fields: dict[str, np.ndarray] = {}
    for message_type in ("02", "21", "22"):  # later types overwrite: 22's quaternion is the pose's own
        chunks = frame.parts.get(message_type)
        if chunks is None:
            continue
        if len(chunks) == 1:
            values, rows = chunks[0].values, chunks[0].rows
        else:
            values = np.concatenate([chunks[k].values for k in range(len(chunks))])
            rows = np.concatenate([chunks[k].rows for k in range(len(chunks))])
        if len(rows) == n and rows.tobytes() == _ORDER[:n].tobytes():  # one comparison of n int64
            table = values.astype(np.float64)
        else:
            table = np.full((n, values.shape[1]), np.nan)
            body = rows < n
            table[rows[body]] = values[body]
        for name in SAMPLE_FIELDS[message_type]:  # views of the table: one conversion per message type
            fields[name] = table[:, COLUMNS[message_type][name]]
    if position_scale != 1.0:
        for name in ("position", "velocity"):
            if name in fields:
                fields[name] *= position_scale
    quaternion = fields.get("quaternion", np.full((n, 4), np.nan))
    return Sample(character, counter, frame.time_code / 1000.0, arrival, names, quaternion,
                  fields.get("angular_velocity"), fields.get("position"), fields.get("velocity"))


_ORDER = np.arange(256)  # segment rows in order, for the usual message's check


def _quadratic_form() -> np.ndarray:
    """M [16,9]: the rotation matrix (row-major) of a quaternion q (w, x, y, z) is vec(q q^T) M / |q|^2:
    so3.quaternion_to_matrix's entries, 1 written as |q|^2, each a sum of the products in q q^T."""
    entries = ("+ww+xx-yy-zz", "+xy+yx-wz-zw", "+xz+zx+wy+yw", "+xy+yx+wz+zw", "+ww-xx+yy-zz", "+yz+zy-wx-xw",
               "+xz+zx-wy-yw", "+yz+zy+wx+xw", "+ww-xx-yy+zz")
    form = np.zeros((4, 4, 9))
    for column, entry in enumerate(entries):
        for sign, i, j in zip(entry[::3], entry[1::3], entry[2::3]):
            form["wxyz".index(i), "wxyz".index(j), column] += 1.0 if sign == "+" else -1.0
    return form.reshape(16, 9)


_QUADRATIC_FORM = _quadratic_form()


def rotations(quaternion: np.ndarray) -> np.ndarray:
    """Rotation matrices [...,3,3] of the quaternions [...,4] (w, x, y, z) a stream carried, each
    normalised (float32 leaves them 1e-7 off unit length); NaN where a quaternion is. One product
    with a constant matrix (`_quadratic_form`): this runs for every live sample, where torch's two
    dozen small operations took over ten times as long (experiments/live_latency.md)."""
    q = np.asarray(quaternion, dtype=np.float64)
    outer = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,))
    return ((outer @ _QUADRATIC_FORM) / (q * q).sum(axis=-1, keepdims=True)).reshape(q.shape[:-1] + (3, 3))
