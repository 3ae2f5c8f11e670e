"""Finding the clips of a batch: walk the inputs, name each clip's output folder, and never stop for one bad path.

Naming (a stable interface): a clip named directly on the command line (a video file or a folder of frames) is
written to ``OUT/<its name, suffix dropped>``; a clip found inside a given folder keeps its path relative to that
folder, suffix dropped (``videos/site1/p7.mp4`` -> ``OUT/site1/p7``).

Hostile trees are expected: a path that cannot be used becomes either a clip that fails with its reason (a
symlink loop or a dangling link with a video suffix, a FIFO named ``x.mp4``) or a :class:`PathProblem` (a folder
that cannot be listed). Folder links are followed, each folder is searched once (loops end there), and the
output folder and any other colonlight output folder (it holds :data:`OUTPUT_MARKER`) are never searched.
A synthetic clip folder (``colonlight synth``: it holds :data:`SYNTH_MARKER`, beside ``clip.mp4``, ``frames/``,
``clean/`` and ``depth/``) is one clip, named by its folder: its recorded video, or its frames if it has none.
Names that are not valid UTF-8 are kept as Python keeps them (``os.fsdecode``: surrogate escapes), so the
output folder gets the same bytes.
"""

from __future__ import annotations

import fnmatch
import os
import stat
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from .errors import os_error_cause
from .frames import IMAGE_SUFFIXES, is_image_folder
from .jobs import ClipJob
from .video import VIDEO_SUFFIXES, is_video

_SIDE_SUFFIXES = frozenset([".json", ".txt", ".csv", ".md", ".yaml", ".yml", ".xml", ".log", ".ini"])
#: The lock file every ``colonlight enhance`` output folder holds (see :mod:`colonlight.outdir`): a folder
#: holding it is an output, never an input.
OUTPUT_MARKER = ".colonlight.lock"
#: The batch's record of every clip, beside the clip folders in the output folder (re-exported by batch).
MANIFEST_FILE = "manifest.json"
#: Names the output folder holds for itself: no clip's folder may take one (``manifest.json.mp4`` would make the
#: folder ``OUT/manifest.json``, and the manifest could never be written again).
RESERVED_NAMES = frozenset({MANIFEST_FILE, OUTPUT_MARKER})
#: The file every synthetic clip folder holds (written last, see :mod:`colonlight.synth.writer`): such a folder
#: is one clip, never searched for clips of its own (its ``clean/`` and ``depth/`` are ground truth, not clips).
SYNTH_MARKER = "synth.json"
#: A synthetic clip folder's recorded video and its frame folder (written by :mod:`colonlight.synth.writer`).
SYNTH_VIDEO, SYNTH_FRAMES = "clip.mp4", "frames"
#: What a synthetic clip folder holds as its clip, in order of preference: the recorded video, its frames.
SYNTH_CLIP_SOURCES = (SYNTH_VIDEO, SYNTH_FRAMES)


def is_synthetic_folder(path: Path) -> bool:
    """A ``colonlight synth`` clip folder (by its :data:`SYNTH_MARKER`)."""
    return os.path.isdir(path) and os.path.isfile(os.path.join(path, SYNTH_MARKER))


def synthetic_folder_of(source: Path) -> Path | None:
    """The synthetic clip folder whose clip ``source`` is (``s0/clip.mp4`` -> ``s0``), else None."""
    source = Path(source)
    return source.parent if source.name in SYNTH_CLIP_SOURCES and is_synthetic_folder(source.parent) else None


def synthetic_clip(folder: Path) -> tuple[Path, str | None]:
    """The clip of a synthetic clip folder, and a one-line problem if it holds none."""
    for name in SYNTH_CLIP_SOURCES:
        if os.path.exists(os.path.join(folder, name)):
            return Path(folder) / name, None
    return Path(folder) / SYNTH_CLIP_SOURCES[0], (
        f"{folder}: a synthetic clip folder with neither {' nor '.join(SYNTH_CLIP_SOURCES)}"
    )


@dataclass(frozen=True)
class PathProblem:
    """A path that is not a clip and was not searched: ``failed`` (a folder that cannot be listed: clips may be
    missing) or merely skipped (a folder reached again through a link, a FIFO, another output folder)."""

    path: str
    message: str  # one line, naming the path
    failed: bool = True


@dataclass
class Discovery:
    jobs: list[ClipJob] = field(default_factory=list)
    problems: list[PathProblem] = field(default_factory=list)


def _strip_suffix(rel: Path) -> Path:
    return rel.with_suffix("") if rel.suffix else rel


def _identity(st: os.stat_result) -> tuple[int, int]:
    return st.st_dev, st.st_ino


def _stat_identity(path: Path) -> tuple[int, int] | None:
    try:
        return _identity(os.stat(path))
    except OSError:
        return None


@dataclass
class _Walk:
    """One walk of an input folder: the folders seen (by device and inode) and the folders never to enter."""

    excluded: frozenset[tuple[int, int]]
    out: Discovery
    seen: dict[tuple[int, int], Path] = field(default_factory=dict)

    def walk(self, root: Path) -> Iterator[tuple[Path, Path, str | None]]:
        """Yield ``(source, relative name, problem)`` for the clips under ``root``, depth first in sorted order.

        An explicit stack, not recursion: a hostile tree may be thousands of folders deep.
        """
        root_id = _stat_identity(root)
        if root_id is None:
            return
        if root_id in self.excluded:
            self.out.problems.append(PathProblem(str(root), f"{root}: skipped: it is the output folder", failed=False))
            return
        self.seen[root_id] = root
        stack = [root]
        while stack:
            folder = stack.pop()
            try:
                with os.scandir(folder) as it:
                    names = sorted(e.name for e in it if not e.name.startswith("."))
            except OSError as exc:
                self.out.problems.append(
                    PathProblem(str(folder), f"{folder}: cannot search this folder: {os_error_cause(exc)}")
                )
                continue
            subfolders: list[Path] = []
            files: list[tuple[Path, str | None]] = []
            for name in names:
                path = folder / name
                suffix = path.suffix.lower()
                side = suffix in IMAGE_SUFFIXES or suffix in _SIDE_SUFFIXES
                try:
                    st = os.stat(path)
                except OSError as exc:
                    if suffix in VIDEO_SUFFIXES:
                        files.append((path, f"{path}: {os_error_cause(exc)}"))
                    elif not side:
                        self.out.problems.append(
                            PathProblem(str(path), f"{path}: skipped: {os_error_cause(exc)}", failed=False)
                        )
                    continue
                if stat.S_ISDIR(st.st_mode):
                    subfolders.append(path)
                elif stat.S_ISREG(st.st_mode):
                    files.append((path, None))
                elif suffix in VIDEO_SUFFIXES:
                    files.append((path, f"{path}: not a regular file"))
                elif not side:
                    self.out.problems.append(
                        PathProblem(str(path), f"{path}: skipped: not a regular file", failed=False)
                    )
            descend: list[Path] = []
            for sub in subfolders:
                ident = _stat_identity(sub)
                if ident is None:  # vanished since the listing
                    continue
                if ident in self.excluded:
                    continue  # the output folder: never an input (not worth a line)
                if ident in self.seen:
                    self.out.problems.append(
                        PathProblem(
                            str(sub),
                            f"{sub}: skipped: the same folder as {self.seen[ident]} (a link), searched once",
                            failed=False,
                        )
                    )
                    continue
                self.seen[ident] = sub
                if os.path.lexists(sub / OUTPUT_MARKER):
                    self.out.problems.append(
                        PathProblem(
                            str(sub),
                            f"{sub}: skipped: a colonlight output folder (it holds {OUTPUT_MARKER})",
                            failed=False,
                        )
                    )
                    continue
                if is_synthetic_folder(sub):
                    source, problem = synthetic_clip(sub)  # one clip, named by its folder: do not descend
                    yield source, sub.relative_to(root), problem
                elif is_image_folder(sub):
                    yield sub, sub.relative_to(root), None  # a frame folder is one clip: do not descend
                else:
                    descend.append(sub)
            for path, problem in files:
                suffix = path.suffix.lower()
                if suffix in IMAGE_SUFFIXES or suffix in _SIDE_SUFFIXES:
                    continue
                if problem is not None or suffix in VIDEO_SUFFIXES or is_video(path):
                    yield path, _strip_suffix(path.relative_to(root)), problem
            stack.extend(reversed(descend))


def _direct(inp: Path) -> tuple[Path, Path, str | None]:
    """A path named on the command line that is not a folder to walk: one clip, maybe already known to fail."""
    # abspath: "." or "videos/.." must not name the clip "." or "..", which would write into (or above) OUT
    rel = Path(_strip_suffix(Path(os.path.basename(os.path.abspath(inp)) or "clip")))
    try:
        st = os.stat(inp)
    except OSError as exc:
        return inp, rel, f"{inp}: {os_error_cause(exc)}"
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        return inp, rel, f"{inp}: not a regular file or folder"
    return inp, rel, None


def discover(
    inputs: Sequence[Path],
    out_root: Path,
    pattern: str | None = None,
    exclude: Sequence[Path] = (),
) -> Discovery:
    """The clips under ``inputs`` (files and folders, walked recursively), with their output folders, and the
    paths that could not be used. Never raises for a bad path.

    ``pattern`` (a glob) keeps clips whose relative path or file name matches. ``exclude``: folders never
    searched (the batch's output folder). Two clips that would share an output folder are told apart by their
    suffix (``clip-mp4``, ``clip-avi``), then by a number (``clip-mp4-2``): see :func:`_unique_names`.
    """
    out = Discovery()
    excluded = frozenset(i for i in (_stat_identity(Path(p)) for p in exclude) if i is not None)
    walker = _Walk(excluded, out)
    found: list[tuple[Path, Path, str | None]] = []
    for inp in inputs:
        inp = Path(inp)
        if is_synthetic_folder(inp):
            source, problem = synthetic_clip(inp)
            found.append((source, _direct(inp)[1], problem))
        elif os.path.isdir(inp) and not is_image_folder(inp):
            had = (len(found), len(out.problems))
            found.extend(walker.walk(inp))
            if len(inputs) > 1 and (len(found), len(out.problems)) == had:  # alone, "no clips found" says it
                out.problems.append(PathProblem(str(inp), f"{inp}: skipped: no clips in this folder", failed=False))
        else:  # a file, a frame folder, or a path that cannot be used (it fails when the clip runs)
            found.append(_direct(inp))
    if pattern:
        found = [
            (src, rel, problem)
            for src, rel, problem in found
            if fnmatch.fnmatch(src.name, pattern)
            or fnmatch.fnmatch(rel.as_posix(), pattern)
            or fnmatch.fnmatch((rel.parent / src.name).as_posix(), pattern)
        ]
    for src, name, problem in _unique_names(found):
        out.jobs.append(ClipJob(source=src, name=name, out_dir=Path(out_root) / name, problem=problem))
    return out


def _unique_names(found: Sequence[tuple[Path, Path, str | None]]) -> Iterator[tuple[Path, str, str | None]]:
    """Each clip once, with an output name no other clip has: two clips writing one folder would skip or
    overwrite each other. A file found twice (named twice, or also inside a given folder) is one clip under its
    own name; names shared by different files get the suffix (``p7-mp4``, ``p7-avi``), then, where that is
    not enough (``a/p7.mp4`` and ``b/p7.mp4``, ``p7.mp4`` and ``p7.MP4``, ``p7.mp4`` beside ``p7-mp4.mov``),
    a number (``p7-mp4-2``); a name that needs neither is never taken by another clip.

    Nor is a clip's folder ever inside another's: ``a.mp4`` beside a folder ``a/`` holding ``frames.mp4`` would
    put ``a/frames/`` (a clip) in ``a/`` (a clip, whose own frames go to ``a/frames/``), and clearing one clip's
    temporaries would delete the other's as it writes them; the outer one takes its suffix (``a-mp4``). Nor does
    a clip take a name the output folder keeps for itself (:data:`RESERVED_NAMES`): ``manifest.json.mp4`` becomes
    ``manifest.json-mp4``, and a clip inside a folder so named fails, saying why."""
    # realpath, unlike Path.resolve, never raises on a link loop
    clips = [(src, rel.as_posix(), problem, os.path.realpath(src)) for src, rel, problem in found]
    sources: dict[str, set[str]] = {}
    for _, rel, _, real in clips:
        sources.setdefault(rel, set()).add(real)
    # the folders that hold another clip's folder, and the output folder's own files: no clip may be written there
    holders = {parent.as_posix() for rel in sources for parent in PurePosixPath(rel).parents} | RESERVED_NAMES
    taken = holders | {rel for rel, reals in sources.items() if len(reals) == 1}  # kept as they are
    seen: set[tuple[str, str]] = set()
    for src, rel, problem, real in clips:
        if (real, rel) in seen:
            continue
        seen.add((real, rel))
        name = rel
        top = rel.split("/", 1)[0]
        if top in RESERVED_NAMES and top != rel and problem is None:  # OUT/manifest.json/<clip>: a folder's name
            problem = (
                f"{src}: its output folder would be inside {top}, a name the output folder keeps for itself "
                "(rename that folder)"
            )
        if len(sources[rel]) > 1 or rel in holders:
            if src.suffix or synthetic_folder_of(src):
                name = f"{rel}-{'synth' if synthetic_folder_of(src) else src.suffix.lstrip('.').lower()}"
            base, n = name, 1
            while name in taken:
                n += 1
                name = f"{base}-{n}"
            taken.add(name)
        yield src, name, problem


def discover_clips(inputs: Sequence[Path], out_root: Path, pattern: str | None = None) -> list[ClipJob]:
    """The clips of :func:`discover` (for callers that need no report of unusable paths)."""
    return discover(inputs, out_root, pattern).jobs


__all__ = [
    "MANIFEST_FILE",
    "OUTPUT_MARKER",
    "RESERVED_NAMES",
    "SYNTH_CLIP_SOURCES",
    "SYNTH_FRAMES",
    "SYNTH_MARKER",
    "SYNTH_VIDEO",
    "VIDEO_SUFFIXES",
    "ClipJob",
    "Discovery",
    "PathProblem",
    "discover",
    "discover_clips",
    "is_synthetic_folder",
    "synthetic_clip",
    "synthetic_folder_of",
]
