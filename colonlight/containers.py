"""Is a video file cut short? Answered from its container's own size fields, read as bytes (no decoding).

Used only to warn, never to count frames (the frames are those that decode): a file that ends before its last
box, element or packet says it ends was cut (an interrupted copy, a recording that stopped). Each rule reads a
few bytes per top-level unit, and at most a bounded number of units, so the check costs little on any file:

* ISO media (mp4, mov, fragmented mp4): the top-level boxes' sizes;
* Matroska/WebM: the Segment's size, or where it is unknown (live recordings), its elements' sizes;
* AVI: the RIFF size;
* MPEG-TS: whole 188/192/204-byte packets;
* MPEG-PS (mpg, vob): the pack headers and PES packet lengths of the file's end.
"""

from __future__ import annotations

import os
from pathlib import Path

_TS_PACKET_SIZES = (188, 192, 204)  # MPEG-TS, M2TS (timecode prefix), TS with FEC bytes
_MAX_UNITS = 1_000_000  # boxes or elements walked at most: the walk stays cheap on any file
_PS_TAIL = 256 * 1024  # bytes of an MPEG-PS file's end walked: many packs (2 KB each on DVD)
_EBML_MAGIC = b"\x1a\x45\xdf\xa3"
_SEGMENT_ID = b"\x18\x53\x80\x67"
_ISO_TOP_BOXES = frozenset({b"ftyp", b"styp", b"moov", b"moof", b"mdat", b"free", b"skip", b"wide", b"sidx", b"mfra"})


def _vint(data: bytes, pos: int) -> tuple[int, int, bool] | None:
    """An EBML variable-size integer at ``pos``: (value, next position, all ones = "unknown size")."""
    if pos >= len(data) or data[pos] == 0:
        return None
    length = 8 - data[pos].bit_length() + 1
    if pos + length > len(data):
        return None
    value = data[pos] & (0xFF >> length)
    for byte in data[pos + 1 : pos + length]:
        value = value << 8 | byte
    return value, pos + length, value == (1 << (7 * length)) - 1


def _read(path: Path, offset: int, n: int) -> bytes:
    with open(path, "rb") as fh:
        fh.seek(offset)
        return fh.read(n)


def declared_end(path: Path) -> int | None:
    """Where the file should end by its container's own top-level size field (RIFF for AVI, the Segment of
    Matroska/WebM), or None where there is none (unknown size, as a live recording writes, or another format)."""
    try:
        head = _read(path, 0, 4096)
    except OSError:
        return None
    if head[:4] == b"RIFF" and len(head) >= 8:
        return 8 + int.from_bytes(head[4:8], "little")
    if head[:4] == _EBML_MAGIC:  # EBML header, then the Segment element
        header = _vint(head, 4)
        if header is None:
            return None
        pos = header[1] + header[0]
        if head[pos : pos + 4] != _SEGMENT_ID:
            return None
        seg = _vint(head, pos + 4)
        return None if seg is None or seg[2] else seg[1] + seg[0]
    return None


def _iso_overrun(path: Path, size: int) -> tuple[str, int] | None:
    """(box type, its end) of a top-level ISO box that runs past ``size``; None if the boxes fit."""
    pos = 0
    with open(path, "rb") as fh:
        for _ in range(_MAX_UNITS):
            if pos >= size:
                return None
            fh.seek(pos)
            head = fh.read(16)
            if len(head) < 8:
                return "box header", pos + 8
            box = int.from_bytes(head[:4], "big")
            kind = head[4:8]
            if box == 1:
                if len(head) < 16:
                    return kind.decode("latin-1"), pos + 16
                box = int.from_bytes(head[8:16], "big")
            elif box == 0:  # extends to the end of the file
                return None
            if box < 8 or kind not in _ISO_TOP_BOXES and not kind.isalnum():
                return None  # not a box structure we can follow: say nothing
            if pos + box > size:
                return kind.decode("latin-1"), pos + box
            pos += box
    return None


def index_cut(path: Path) -> tuple[int, int] | None:
    """(file size, where the box ends) if ``path`` is an ISO media file (mp4, mov) cut inside its index, the
    top-level 'moov' box; None otherwise (no ISO file, boxes that fit, or a cut elsewhere)."""
    try:
        size = os.stat(path).st_size
        if _read(path, 0, 8)[4:8] not in (b"ftyp", b"moov", b"free", b"wide", b"mdat"):
            return None
        box = _iso_overrun(path, size)
    except OSError:
        return None
    return (size, box[1]) if box is not None and box[0] == "moov" else None


def _ebml_overrun(path: Path, size: int) -> int | None:
    """The end of a Matroska element (after the EBML header, in a Segment of unknown size) that runs past
    ``size``; elements of unknown size (the Segment, live Clusters) are entered, the others skipped."""
    pos = 0
    with open(path, "rb") as fh:
        for _ in range(_MAX_UNITS):
            if pos >= size:
                return None
            fh.seek(pos)
            head = fh.read(12)
            ident = _vint(head, 0)
            if ident is None:
                return None if len(head) >= 12 else pos + 12
            length = _vint(head, ident[1])
            if length is None:
                return None if len(head) >= 12 else pos + 12
            value, body, unknown = length
            if unknown:
                pos += body  # a master element of unknown size: its children follow
                continue
            if pos + body + value > size:
                return pos + body + value
            pos += body + value
    return None


def _ps_walk(tail: bytes, start: int) -> int | None:
    """Walk MPEG-PS units from ``start`` in ``tail`` to its end: -1 if they end exactly there, the end of a
    unit that runs past it, or None if the bytes are not a unit sequence (a false start)."""
    p = start
    n = len(tail)
    while p < n:
        if n - p < 4:
            return p + 4 if tail[p:n] == b"\x00\x00\x01"[: n - p] else None
        if tail[p : p + 3] != b"\x00\x00\x01":
            return None
        code = tail[p + 3]
        if code == 0xB9:  # program end
            length = 4
        elif code == 0xBA:  # pack header: MPEG-2 (14 bytes + stuffing) or MPEG-1 (12 bytes)
            if n - p < 5:
                return p + 14
            if tail[p + 4] >> 6 == 1:
                if n - p < 14:
                    return p + 14
                length = 14 + (tail[p + 13] & 7)
            elif tail[p + 4] >> 4 == 2:
                length = 12
            else:
                return None
        elif code >= 0xBB:  # system header or a PES packet: 16-bit length after the start code
            if n - p < 6:
                return p + 6
            length = 6 + int.from_bytes(tail[p + 4 : p + 6], "big")
        else:
            return None
        if p + length > n:
            return p + length
        p += length
    return -1


def _ps_overrun(path: Path, size: int) -> int | None:
    """The end of the MPEG-PS pack or PES packet the file ends inside, or None if its last packet is whole."""
    base = max(0, size - _PS_TAIL)
    tail = _read(path, base, size - base)
    starts = [0] if base == 0 else []
    at = tail.find(b"\x00\x00\x01\xba")
    while at >= 0 and len(starts) < 16:
        starts.append(at)
        at = tail.find(b"\x00\x00\x01\xba", at + 1)
    for start in starts:
        end = _ps_walk(tail, start)
        if end is not None:
            return None if end < 0 else base + end
    return None


def truncation_reason(path: Path, format_name: str) -> str | None:
    """Why the file at ``path`` (demuxed by FFmpeg's ``format_name``) looks cut short; None if it does not."""
    try:
        size = os.stat(path).st_size
        head = _read(path, 0, 8)
        end = declared_end(path)
        if end is not None and end > size:
            return f"the file ends at byte {size} but its container says it ends at byte {end}"
        fmt = format_name.split(",")[0]
        if fmt == "mpegts" and all(size % n for n in _TS_PACKET_SIZES):
            return f"the file ends inside a transport-stream packet ({size} bytes is no whole number of packets)"
        if fmt == "mov" or head[4:8] in (b"ftyp", b"styp", b"moov", b"mdat"):
            box = _iso_overrun(path, size)
            if box is not None:
                return f"the file ends at byte {size} but its '{box[0]}' box says it ends at byte {box[1]}"
        if head[:4] == _EBML_MAGIC and end is None:
            element = _ebml_overrun(path, size)
            if element is not None:
                return f"the file ends at byte {size} but its last element says it ends at byte {element}"
        if fmt == "mpeg":
            packet = _ps_overrun(path, size)
            if packet is not None:
                return f"the file ends at byte {size}, inside a program-stream packet that ends at byte {packet}"
    except OSError:
        return None
    # Not used: header frame counts (an AVI with audio declares one frame more than it holds) and durations
    # (the audio may outlast the video): either would flag sound files.
    return None
