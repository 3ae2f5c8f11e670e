"""Damaged clips for the fuzz suite: real small seed clips and the ways a file gets broken, as hypothesis strategies.

A case is a seed clip (made by ``tests/media.py``: 32x32, 16 frames, in every container the CLI finds) plus a
list of damages applied in order: byte flips, a cut at any offset, byte ranges duplicated or dropped (a
retransmitted or lost chunk of a copy), packets dropped or duplicated by a remux with PyAV (a recorder that lost
or repeated frames), the head of another container spliced onto the body (a header from another file), and the
name's suffix swapped for another container's. Cases are plain frozen dataclasses, so that a failing one can be
kept as an explicit ``@example``.

``COLONLIGHT_FUZZ_EXAMPLES`` (e.g. 500) sets how many cases each test runs; CI runs the small defaults, in a fixed
order (derandomized, no example database), so that a CI failure reproduces anywhere.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from ..media import make_clip

SIZE = (32, 32)
FRAMES = 16
MPEG4 = ("-c:v", "mpeg4", "-q:v", "2")
VP8 = ("-c:v", "libvpx", "-b:v", "200k")

#: seed name -> (file name, maker). The name's suffix is the one the clip is found by.
SEEDS: dict[str, tuple[str, Callable[[Path], Path]]] = {
    "mp4": ("c.mp4", lambda p: make_clip(p, FRAMES, 25, SIZE)),
    "mp4-faststart": ("c.mp4", lambda p: make_clip(p, FRAMES, 25, SIZE, output_args=["-movflags", "+faststart"])),
    "mov": ("c.mov", lambda p: make_clip(p, FRAMES, 25, SIZE)),
    "mkv-audio": ("c.mkv", lambda p: make_clip(p, FRAMES, 25, SIZE, audio=True)),
    "ts": ("c.ts", lambda p: make_clip(p, FRAMES, 25, SIZE)),
    "avi": ("c.avi", lambda p: make_clip(p, FRAMES, 25, SIZE, codec_args=MPEG4)),
    "webm": ("c.webm", lambda p: make_clip(p, FRAMES, 25, SIZE, codec_args=VP8)),
}
SUFFIXES = sorted({Path(name).suffix for name, _ in SEEDS.values()})
#: Frames a sound seed gives at the default 18 fps (16 frames at 25 fps).
SEED_OUTPUT_FRAMES = 12


def make_seeds(folder: Path) -> dict[str, Path]:
    """Every seed clip, in ``folder/<seed>/``."""
    return {name: make(folder / name / file) for name, (file, make) in SEEDS.items()}


# ------------------------------------------------------------------------------------------------------ damages


@dataclass(frozen=True)
class Flip:
    """XOR the byte at ``pos`` (modulo the length) with ``mask``."""

    pos: int
    mask: int

    def apply(self, data: bytes, seeds: dict[str, bytes]) -> bytes:
        if not data:
            return data
        out = bytearray(data)
        out[self.pos % len(out)] ^= self.mask
        return bytes(out)


@dataclass(frozen=True)
class Cut:
    """Keep the first ``keep`` bytes (modulo the length): an interrupted copy or recording."""

    keep: int

    def apply(self, data: bytes, seeds: dict[str, bytes]) -> bytes:
        return data[: self.keep % len(data)] if data else data


@dataclass(frozen=True)
class Duplicate:
    """Repeat ``length`` bytes from ``start`` (modulo the length) right after themselves: a chunk sent twice."""

    start: int
    length: int

    def apply(self, data: bytes, seeds: dict[str, bytes]) -> bytes:
        if not data:
            return data
        a = self.start % len(data)
        chunk = data[a : a + self.length]
        return data[: a + len(chunk)] + chunk + data[a + len(chunk) :]


@dataclass(frozen=True)
class Drop:
    """Remove ``length`` bytes from ``start`` (modulo the length): a chunk lost."""

    start: int
    length: int

    def apply(self, data: bytes, seeds: dict[str, bytes]) -> bytes:
        if not data:
            return data
        a = self.start % len(data)
        return data[:a] + data[a + self.length :]


@dataclass(frozen=True)
class Splice:
    """The first ``head`` bytes of seed ``other`` followed by this file from byte ``body`` on (both modulo the
    lengths): a header from another container, e.g. Matroska's EBML head on an MP4 body."""

    other: str
    head: int
    body: int

    def apply(self, data: bytes, seeds: dict[str, bytes]) -> bytes:
        donor = seeds[self.other]
        return donor[: self.head % len(donor)] + (data[self.body % len(data) :] if data else b"")


ByteDamage = Flip | Cut | Duplicate | Drop | Splice


@dataclass(frozen=True)
class Packets:
    """Remux the seed's streams with PyAV, leaving out the video packets numbered in ``drop`` and writing those
    in ``duplicate`` twice (the copy one tick later, as muxers refuse equal timestamps in some containers)."""

    drop: tuple[int, ...] = ()
    duplicate: tuple[int, ...] = ()

    def remux(self, src: Path, dst: Path) -> None:
        import av

        with av.open(str(src)) as inp, av.open(str(dst), "w") as out:
            streams = {s.index: out.add_stream_from_template(s) for s in inp.streams if s.type in ("video", "audio")}
            n_video = 0
            for packet in inp.demux(*[s for s in inp.streams if s.index in streams]):
                if packet.dts is None and packet.size == 0:
                    continue  # the flush packet
                copies = 1
                if packet.stream.type == "video":
                    number = n_video
                    n_video += 1
                    if number in self.drop:
                        continue
                    copies = 2 if number in self.duplicate else 1
                for k in range(copies):
                    p = av.Packet(bytes(packet))
                    p.pts = None if packet.pts is None else packet.pts + k
                    p.dts = None if packet.dts is None else packet.dts + k
                    p.time_base = packet.time_base
                    p.is_keyframe = packet.is_keyframe
                    p.stream = streams[packet.stream.index]
                    # the muxer may refuse one (timestamps): the file goes on without it
                    with contextlib.suppress(av.error.FFmpegError):
                        out.mux(p)


@dataclass(frozen=True)
class Case:
    """A seed clip, damaged by ``packets`` (if any) and then by ``damages`` in order, named ``clip`` + ``suffix``
    (the seed's own suffix if None)."""

    seed: str
    damages: tuple[ByteDamage, ...] = ()
    packets: Packets | None = None
    suffix: str | None = None

    @property
    def name(self) -> str:
        return "clip" + (self.suffix or Path(SEEDS[self.seed][0]).suffix)

    def write(self, seeds: dict[str, Path], folder: Path) -> Path:
        """Write the damaged clip into ``folder`` and return its path."""
        folder.mkdir(parents=True, exist_ok=True)
        src = seeds[self.seed]
        dst = folder / self.name
        if self.packets is not None:
            remuxed = folder / (".remux" + src.suffix)
            self.packets.remux(src, remuxed)
            data = remuxed.read_bytes()
            remuxed.unlink()
        else:
            data = src.read_bytes()
        seed_bytes = {name: p.read_bytes() for name, p in seeds.items()}
        for damage in self.damages:
            data = damage.apply(data, seed_bytes)
        dst.write_bytes(data)
        return dst


# --------------------------------------------------------------------------------------------------- strategies

seed_names = st.sampled_from(sorted(SEEDS))
offsets = st.integers(0, 1 << 16)  # taken modulo the file's length (the seeds are 1-7 KB)
spans = st.integers(1, 2048)

flips = st.builds(Flip, offsets, st.sampled_from([0x01, 0x80, 0xFF]) | st.integers(1, 255))
cuts = st.builds(Cut, offsets)
duplicates = st.builds(Duplicate, offsets, spans)
drops = st.builds(Drop, offsets, spans)
splices = st.builds(Splice, seed_names, st.integers(0, 4096), offsets)
byte_damages = st.one_of(flips, cuts, duplicates, drops, splices)
packet_numbers = st.sets(st.integers(0, FRAMES - 1), max_size=6).map(lambda s: tuple(sorted(s)))
suffixes = st.none() | st.sampled_from(SUFFIXES)

#: The families, each one test (so that each runs however few cases CI allows).
FAMILIES: dict[str, st.SearchStrategy[Case]] = {
    "flips": st.builds(Case, seed_names, st.lists(flips, min_size=1, max_size=8).map(tuple)),
    "cuts": st.builds(Case, seed_names, st.tuples(cuts)),
    "chunks": st.builds(Case, seed_names, st.lists(duplicates | drops, min_size=1, max_size=3).map(tuple)),
    "packets": st.builds(Case, seed_names, st.just(()), st.builds(Packets, packet_numbers, packet_numbers)),
    "foreign": st.builds(
        Case, seed_names, st.lists(splices, max_size=1).map(tuple), st.none(), st.sampled_from(SUFFIXES)
    ),
    "mixed": st.builds(
        Case,
        seed_names,
        st.lists(byte_damages, min_size=1, max_size=4).map(tuple),
        st.none() | st.builds(Packets, packet_numbers, packet_numbers),
        suffixes,
    ),
}

EXAMPLES_ENV = "COLONLIGHT_FUZZ_EXAMPLES"


def fuzz_settings(default: int) -> settings:
    """``default`` cases (``COLONLIGHT_FUZZ_EXAMPLES`` if set), no deadline (a case is bounded by its own
    timeout instead), in a fixed order without an example database: a failure in CI reproduces anywhere."""
    raw = os.environ.get(EXAMPLES_ENV, "").strip()
    n = int(raw) if raw.isdigit() and int(raw) > 0 else default
    return settings(
        max_examples=n,
        deadline=None,
        derandomize=True,
        database=None,
        print_blob=False,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
