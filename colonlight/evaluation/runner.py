"""Run methods on clips and measure them: lighting consistency, exposure, tracking, COLMAP, cost.

Tracking runs once per brightness setting (``fixed``: the paper's, a = b = 0; ``affine``: fitted; see
:mod:`.tracker`); COLMAP does not depend on it and runs once. Clips with clean frames also get four reference
rows (:mod:`.oracles`): the clean frames themselves, ``oracle-curve``, ``oracle-gain-gamma`` and ``oracle-gamma``
(the ceilings of three families of one global correction per frame), and the frames the
input fails while the clean frames pass are classified and checked for rescues (:mod:`.breakdown`).

Per clip, what depends only on the input is computed once (content masks, the correspondences used for the
motion-compensated SSIM, the input's scores); then every method streams the clip once, its enhanced frames
are kept in memory (clips are short, at working size) and scored. One clip is in memory at a time.

A method that cannot be built (weights not installed, the authors' checkpoint absent) is skipped with its
one-line reason; a clip that cannot be loaded is recorded as failed with its one-line reason; the rest goes on.

What a run records: :mod:`.records`; the one row per method made from it: :mod:`.summary` (both re-exported here).
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..content import (
    DEFAULT_CONTENT,
    content_setting,
    content_stream,
    find_content_area,
    parse_content,
)
from ..content_mask import ContentMask
from ..errors import ColonlightError, OptionError
from ..limits import DEFAULT_FPS
from ..methods import Method, available_methods, create_method
from ..methods.options import methods_kwargs
from ..metrics import clip_lighting, content_masks, mean_luma
from .breakdown import clip_failures
from .cache import ResultCache
from .clips import DEFAULT_MAX_SIZE, ClipRef, EvalClip
from .colmap import ColmapSettings, run_colmap
from .consistency import (
    Correspondence,
    depth_correspondences,
    exposure_fractions,
    flow_correspondences,
    motion_compensated_ssim,
)
from .oracles import CLEAN_LABEL, CURVE_LABEL, GAIN_GAMMA_LABEL, GAMMA_LABEL, REFERENCE_LABELS, oracle_frames
from .records import ClipRecord, EvaluationResult, MethodClipResult
from .summary import INPUT_NAME, failure_breakdown, input_label, nanmean, nanmedian, summarize
from .tracker import BRIGHTNESS_MODES, TrackerSettings

#: Why the reference rows are absent when no clip has clean frames.
NO_CLEAN_REASON = "no clip has clean frames (synthetic clips, or clean frames of your own)"

#: The benchmark's methods, in table order.
DEFAULT_METHODS = ("none", "he", "clahe", "deflicker", "zerodce", "zerodce++", "rnn")
STRIP_FRAMES = 6
STRIP_HEIGHT = 96

Progress = Callable[[str, dict[str, Any]], None]


@dataclass(frozen=True)
class EvalMethod:
    """A method to evaluate: a table label, a registry name and its options."""

    label: str
    name: str
    options: tuple[tuple[str, Any], ...] = ()

    @staticmethod
    def of(label: str, name: str, **options: Any) -> EvalMethod:
        return EvalMethod(label, name, tuple(sorted((k, v) for k, v in options.items() if v is not None)))

    def build(self) -> Method:
        return create_method(self.name, **dict(self.options))


def method_list(
    names: Sequence[str],
    authors_checkpoint: Path | str | None = None,
    device: str = "cpu",
    chosen: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[EvalMethod]:
    """Methods by registry name (``rnn`` is ours, labelled ``rnn (ours)``); with ``authors_checkpoint``, the
    authors' released model is added after ours as ``rnn (authors)``. ``chosen``: each method's options, as
    :func:`colonlight.methods.options.methods_kwargs` makes them from a user's (default: the declared ones, on
    ``device``); the authors' row takes rnn's but its weights. Unknown names raise :class:`OptionError`."""
    known = available_methods()
    bad = [name for name in names if name not in known]
    if bad:
        raise OptionError(f"unknown method {bad[0]!r}; choose from {', '.join(known)}")
    rows = [*names, *(["rnn"] if authors_checkpoint is not None and "rnn" not in names else [])]
    kwargs = dict(methods_kwargs(rows, {}, {"device": device})) if chosen is None else chosen
    out = [EvalMethod.of("rnn (ours)" if name == "rnn" else name, name, **kwargs.get(name, {})) for name in names]
    if authors_checkpoint is not None:
        authors = EvalMethod.of("rnn (authors)", "rnn", **{**kwargs.get("rnn", {}), "weights": str(authors_checkpoint)})
        out.insert(names.index("rnn") + 1 if "rnn" in names else len(out), authors)
    return out


# ----------------------------------------------------------------------------------------------- scoring


def _correspondences(clip: EvalClip) -> tuple[str, list[Correspondence]]:
    if clip.synthetic:
        assert clip.depths is not None and clip.poses is not None and clip.K is not None
        return "depth+pose", depth_correspondences(clip.depths, clip.poses, clip.K)
    return "optical flow", flow_correspondences(clip.frames)


NO_DEPTH_REASON = "no depth: tracking needs a synthetic clip's known depth"


def _track(
    clip: EvalClip, frames: list[np.ndarray], settings: TrackerSettings, scene: np.ndarray | None = None
) -> dict[str, Any]:
    """Track the enhanced frames with known depth; per-clip pose errors are medians over frames 1.. (a diverged
    track's errors are astronomically large, so a mean would say nothing), maxima flag the worst frame.
    ``tracked_fraction``: the fraction of frames 1.. that did not fail; ``frame_ok`` and ``keyframe_of`` per
    frame feed the failure breakdown."""
    from .tracker import track_clip

    assert clip.depths is not None and clip.K is not None
    t0 = time.perf_counter()
    with np.errstate(all="ignore"):  # a diverging track overflows; that is a result (failure), not a warning
        res = track_clip(frames, clip.depths, clip.K, clip.poses, settings, scene)
    out: dict[str, Any] = {
        "applicable": True,
        "brightness": settings.brightness,
        "success": bool(res.success),
        "tracked_fraction": float(np.mean(res.frame_ok[1:])) if len(res.frame_ok) > 1 else 1.0,
        "frame_ok": [bool(x) for x in res.frame_ok],
        "keyframe_of": [int(x) for x in res.keyframe_of],
        "failed_at": res.failed_at,
        "failure_reason": res.failure_reason,
        "seconds": time.perf_counter() - t0,
        "converged_fraction": float(np.mean(res.converged)),
        "residual_median": nanmedian(res.residual[1:]),
    }
    te, re = res.translation_error_m, res.rotation_error_deg
    if te is not None and re is not None and len(te) > 1:
        te1, re1 = (np.nan_to_num(np.asarray(x[1:], np.float64), nan=np.inf) for x in (te, re))
        held = slice(0, (res.failed_at - 1) if res.failed_at is not None else len(te1))  # frames before failure
        out.update(
            translation_error_m_mean_tracked=float(te1[held].mean()) if te1[held].size else None,
            rotation_error_deg_mean_tracked=float(re1[held].mean()) if re1[held].size else None,
            translation_error_m_median=float(np.median(te1)),
            rotation_error_deg_median=float(np.median(re1)),
            translation_error_m_max=float(np.max(te1)),
            rotation_error_deg_max=float(np.max(re1)),
            translation_error_m=[float(x) for x in te],
            rotation_error_deg=[float(x) for x in re],
        )
    if res.drift_translation_m is not None:
        out["drift_translation_m_final"] = float(res.drift_translation_m[-1])
    return out


def _colmap(clip: EvalClip, frames: list[np.ndarray], settings: ColmapSettings) -> dict[str, Any]:
    return run_colmap(frames, clip.K, clip.poses, clip.fps, settings).to_dict()


def _strip_indices(n: int, k: int = STRIP_FRAMES) -> list[int]:
    return sorted({round(x) for x in np.linspace(0, n - 1, min(k, n))})


def _thumb(frame: np.ndarray) -> np.ndarray:
    h, w = frame.shape[:2]
    if h <= STRIP_HEIGHT:
        return frame
    return cv2.resize(frame, (max(1, round(w * STRIP_HEIGHT / h)), STRIP_HEIGHT), interpolation=cv2.INTER_AREA)


def _warm_up(method: Method, frames: Sequence[np.ndarray]) -> None:
    """Run a throwaway stream on a few frames so one-off costs (lazy imports, first torch calls, allocator
    growth) do not land in the first clip's timing. A method that fails here fails again when scored, where its
    error is recorded for it alone."""
    with suppress(Exception):
        stream = method.stream()
        for f in frames[:3]:
            stream.push(f)
        stream.flush()


def _clip_error(source: str, exc: Exception) -> str:
    """One line naming ``source`` for a clip that could not be loaded or scored."""
    if isinstance(exc, ColonlightError):
        text = str(exc)
        return text if text.startswith(f"{source}:") else f"{source}: {text}"
    return f"{source}: cannot evaluate: {type(exc).__name__}: {exc}".splitlines()[0]


def _run_method(
    method: Method, frames: list[np.ndarray], content: str = DEFAULT_CONTENT
) -> tuple[list[np.ndarray], list[float | None], float, float]:
    """Enhanced frames, per-frame gammas, and wall and CPU milliseconds per frame (the method alone, no I/O), shown
    the ``content`` area as ``colonlight enhance`` shows it (so a clip's scores are those of what it writes).

    CPU time (this process, all its threads) is kept beside wall time because on a shared machine wall time
    also counts other jobs' load."""
    out: list[np.ndarray] = []
    gammas: list[float | None] = []
    stream = content_stream(method, content)
    c0, t0 = time.process_time(), time.perf_counter()
    for f in frames:
        for r in stream.push(f):
            out.append(r.frame)
            gammas.append(r.gamma)
    for r in stream.flush():
        out.append(r.frame)
        gammas.append(r.gamma)
    n = max(1, len(frames))
    ms, cpu_ms = 1000.0 * (time.perf_counter() - t0) / n, 1000.0 * (time.process_time() - c0) / n
    if len(out) != len(frames):
        raise RuntimeError(f"method {method.name} returned {len(out)} frames for {len(frames)}")
    return out, gammas, ms, cpu_ms


@dataclass
class _ClipContext:
    """What scoring any frames of one clip needs, computed once from the input."""

    clip: EvalClip
    masks: list[np.ndarray]
    corrs: list[Correspondence]
    ssim_in: list[float]
    dark_in: float
    bright_in: float
    modes: tuple[str, ...]
    colmap: bool
    tracker: bool
    colmap_settings: ColmapSettings
    tracker_settings: TrackerSettings
    cache: ResultCache | None
    scene: np.ndarray | None = None  # where the tracker may choose points (None: everywhere)


def scene_mask(clip: EvalClip, content: str) -> np.ndarray | None:
    """Where the clip's frames show the scene, for the tracker (None: every pixel): the area of the mask given as
    ``content``, else the content area ``colonlight enhance`` finds on the input frames, whatever the methods
    are shown: a scope's border and on-screen text are not scene to a SLAM system either way."""
    content = parse_content(content)  # evaluate_clip is public: "AUTO" is a word, not a mask's path
    if isinstance(content, ContentMask):  # the area the methods are shown, read once for the run
        area = content.area
        if area.fov.shape != clip.frames[0].shape[:2]:
            return None  # another size: every method's clip fails on it before it is tracked
    else:
        area = find_content_area(clip.frames, clip.name).area
    return None if area.is_full else area.mask


def _score(
    ctx: _ClipContext, label: str, out: list[np.ndarray], gammas: list[float | None], ms: float, cpu_ms: float
) -> MethodClipResult:
    """Every score of one method's frames on the clip (tracking once per brightness setting, COLMAP once)."""
    clip = ctx.clip
    r = MethodClipResult(clip=clip.name, method=label, frames=len(clip.frames))
    r.ms_per_frame, r.cpu_ms_per_frame = ms, cpu_ms
    light = clip_lighting(clip.frames, out, clip.clean, masks=ctx.masks)
    r.flicker_in, r.flicker_out = light.flicker_in, light.flicker_out
    r.mean_luma_in, r.mean_luma_out = light.mean_luma_in, light.mean_luma_out
    r.psnr_in, r.psnr_out = light.psnr_in, light.psnr_out
    r.luma_out = [float(x) for x in mean_luma(out, ctx.masks)]
    r.gammas = gammas if any(g is not None for g in gammas) else None
    series = motion_compensated_ssim(out, ctx.corrs, ctx.masks)
    r.ssim_series = [float(x) for x in series]
    r.ssim_in, r.ssim_out = nanmean(ctx.ssim_in), nanmean(series)
    r.dark_in, r.bright_in = ctx.dark_in, ctx.bright_in
    r.dark_out, r.bright_out = exposure_fractions(out, ctx.masks)
    truth = [clip.K, *(clip.poses or []), *(clip.depths or [])]
    if ctx.tracker:
        r.tracking = {}
        for mode in ctx.modes:
            if not clip.synthetic:
                r.tracking[mode] = {"applicable": False, "reason": NO_DEPTH_REASON}
                continue
            settings = replace(ctx.tracker_settings, brightness=mode)
            scene = [] if ctx.scene is None else [ctx.scene]  # no mask, no change: earlier results stay cached
            r.tracking[mode] = _scored(
                ctx.cache, "tracker", [*out, *truth, *scene], {"settings": asdict(settings)},
                partial(_track, clip, out, settings, ctx.scene),
            )  # fmt: skip
    if ctx.colmap:  # COLMAP does not depend on the tracker's brightness setting: once per method
        r.colmap = _scored(
            ctx.cache, "colmap", [*out, *truth], {"settings": asdict(ctx.colmap_settings), "fps": clip.fps},
            partial(_colmap, clip, out, ctx.colmap_settings),
        )  # fmt: skip
    return r


def _reference_frames(clip: EvalClip, label: str) -> tuple[list[np.ndarray], list[float | None], float, float]:
    """The clean frames, or an oracle's corrected frames, with their gammas and cost (ms/frame wall, CPU)."""
    assert clip.clean is not None
    c0, t0 = time.process_time(), time.perf_counter()
    gammas: list[float | None]
    if label == CLEAN_LABEL:
        out, gammas = list(clip.clean), [None] * len(clip.clean)
    else:
        out, gammas = oracle_frames(clip.frames, clip.clean, label)
    n = max(1, len(clip.frames))
    return out, gammas, 1000.0 * (time.perf_counter() - t0) / n, 1000.0 * (time.process_time() - c0) / n


def _errored(clip: EvalClip, label: str, exc: Exception) -> MethodClipResult:
    r = MethodClipResult(clip=clip.name, method=label, frames=len(clip.frames))
    if isinstance(exc, ColonlightError):
        r.error = str(exc)
    else:
        r.error = f"{label} failed: {type(exc).__name__}: {exc}".splitlines()[0]
        r.detail = traceback.format_exc()
    return r


def evaluate_clip(
    clip: EvalClip,
    methods: Sequence[tuple[EvalMethod, Method]],
    *,
    colmap: bool = True,
    tracker: bool = True,
    colmap_settings: ColmapSettings | None = None,
    tracker_settings: TrackerSettings | None = None,
    brightness: Sequence[str] = BRIGHTNESS_MODES,
    oracles: bool = True,
    keep_strip: bool = False,
    progress: Progress | None = None,
    cache: ResultCache | None = None,
    content: str = DEFAULT_CONTENT,
) -> tuple[ClipRecord, dict[str, list[np.ndarray]]]:
    """Score every method on one loaded clip; returns its record and (if ``keep_strip``) frame thumbnails.

    ``brightness``: the tracker's brightness settings to track in (``tracker_settings.brightness`` is replaced
    by each). ``oracles``: when the clip has clean frames, add the reference rows (clean and the three oracles)
    before the methods and the breakdown of the input's failures. ``cache``: reuse tracking and
    COLMAP results of byte-identical frames (see :mod:`.cache`). ``content``: what the methods see
    (:mod:`colonlight.content`; ``auto``, as ``colonlight enhance``, ``full``, or a mask image's path)."""
    modes = _modes(brightness)
    masks = content_masks(clip.frames)
    kind, corrs = _correspondences(clip)
    lum_in = mean_luma(clip.frames, masks)
    ssim_in = motion_compensated_ssim(clip.frames, corrs, masks)
    dark_in, bright_in = exposure_fractions(clip.frames, masks)
    ctx = _ClipContext(
        clip, masks, corrs, [float(x) for x in ssim_in], dark_in, bright_in, modes, colmap, tracker,
        colmap_settings or ColmapSettings(), tracker_settings or TrackerSettings(), cache,
        scene_mask(clip, content) if tracker and clip.synthetic else None,
    )  # fmt: skip
    record = ClipRecord(
        name=clip.name,
        info=clip.describe(),
        correspondence=kind,
        valid_fraction=float(np.mean([c.valid.mean() for c in corrs])) if corrs else 0.0,
        luma_in=[float(x) for x in lum_in],
        ssim_in_series=[float(x) for x in ssim_in],
    )
    idx = _strip_indices(len(clip.frames))
    strips: dict[str, list[np.ndarray]] = {"input": [_thumb(clip.frames[i]) for i in idx]} if keep_strip else {}
    references = REFERENCE_LABELS if oracles and clip.clean is not None else ()
    for label in references:
        try:
            out, gammas, ms, cpu_ms = _reference_frames(clip, label)
            record.results[label] = _score(ctx, label, out, gammas, ms, cpu_ms)
            if keep_strip and label == CLEAN_LABEL:
                strips[label] = [_thumb(out[i]) for i in idx]
        except Exception as exc:  # noqa: BLE001 - a reference row's bug must not lose the methods' results
            record.results[label] = _errored(clip, label, exc)
        if progress:
            progress("method", {"clip": clip.name, "method": label, "error": record.results[label].error})
    for spec, method in methods:
        try:
            out, gammas, ms, cpu_ms = _run_method(method, clip.frames, content)
            record.results[spec.label] = _score(ctx, spec.label, out, gammas, ms, cpu_ms)
            if keep_strip and spec.name != INPUT_NAME:  # the input's row already shows it
                strips[spec.label] = [_thumb(out[i]) for i in idx]
        except Exception as exc:  # noqa: BLE001 - one method's bug must not lose the other results
            record.results[spec.label] = _errored(clip, spec.label, exc)
        if progress:
            progress("method", {"clip": clip.name, "method": spec.label, "error": record.results[spec.label].error})
    input_label = next((spec.label for spec, _ in methods if spec.name == INPUT_NAME), None)
    if references and tracker and input_label is not None and clip.synthetic:
        assert clip.clean is not None
        tracks = {label: r.tracking for label, r in record.results.items() if r.tracking and not r.error}
        record.input_failures = clip_failures(
            clip.frames,
            clip.clean,
            clip.lighting,
            tracks,
            input_label,
            CLEAN_LABEL,
            clip.meta.get("camera_gamma"),
        )
    return record, strips


def _modes(brightness: Sequence[str] | str) -> tuple[str, ...]:
    """The brightness settings in table order (fixed first: the paper's); ``both`` means all."""
    wanted = (
        BRIGHTNESS_MODES
        if brightness == "both"
        else tuple(dict.fromkeys([brightness] if isinstance(brightness, str) else brightness))
    )
    bad = [m for m in wanted if m not in BRIGHTNESS_MODES]
    if bad or not wanted:
        raise ValueError(f"unknown brightness setting {', '.join(bad) or '(none)'}; choose fixed, affine or both")
    return tuple(m for m in BRIGHTNESS_MODES if m in wanted)


def _scored(
    cache: ResultCache | None,
    kind: str,
    arrays: list[np.ndarray | None],
    params: dict[str, Any],
    compute: Callable[[], dict[str, Any]],
) -> dict[str, Any]:
    return compute() if cache is None else cache.get_or_compute(kind, arrays, params, compute)


def build_methods(
    methods: Sequence[EvalMethod],
) -> tuple[list[tuple[EvalMethod, Method]], dict[str, str], list[dict[str, Any]]]:
    """Build each method once: ``(built, skipped label -> one-line reason, descriptions of the built)``."""
    built, skipped, described = [], {}, []
    for spec in methods:
        try:
            m = spec.build()
        except (ColonlightError, OSError) as exc:
            skipped[spec.label] = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            continue
        built.append((spec, m))
        described.append(
            {
                "label": spec.label,
                "name": spec.name,
                "options": dict(spec.options),
                "parameters": m.parameters(),
                "model": m.model_info(),
            }
        )
    return built, skipped, described


def evaluate_clips(
    clips: Iterable[ClipRef | EvalClip],
    methods: Sequence[EvalMethod],
    *,
    colmap: bool = True,
    tracker: bool = True,
    max_size: int | None = DEFAULT_MAX_SIZE,
    fps: float = DEFAULT_FPS,
    max_frames: int | None = None,
    colmap_settings: ColmapSettings | None = None,
    tracker_settings: TrackerSettings | None = None,
    brightness: Sequence[str] | str = BRIGHTNESS_MODES,
    oracles: bool = True,
    strips: int = 3,
    threads: int | None = 1,
    progress: Progress | None = None,
    cache_dir: Path | None = None,
    content: str = DEFAULT_CONTENT,
) -> EvaluationResult:
    """Evaluate ``methods`` on ``clips`` (loaded one at a time); see the module docstring.

    ``cache_dir``: keep tracking and COLMAP results there and reuse them for byte-identical frames, so a re-run
    (another method added, an interrupted run finished) computes only what is new.
    ``strips``: how many clips keep before/after thumbnails for the report. ``tracker_settings``: a
    :class:`colonlight.evaluation.tracker.TrackerSettings` (default thresholds when ``None``); ``brightness``:
    the settings tracked in (``"both"``, or any of ``fixed``/``affine``). ``content``: what the methods see
    (``auto``, the default as in ``colonlight enhance``: the field of view inside a black border, less fixed text;
    ``full``; or a mask image's path, :func:`colonlight.content.parse_content`). ``oracles``: reference rows (clean and
    the three oracles) on clips with clean frames; without any such clip they are listed as skipped with the
    reason. ``threads``:
    torch and OpenCV threads while evaluating (restored afterwards; ``None`` leaves them). One by default, so
    that every method's cost is measured alike and OpenMP spinning on a busy machine does not inflate it
    (the 64-px network took 270 ms/frame with 2 threads beside other jobs, 12 ms with one).
    """
    with _threads(threads):
        return _evaluate_clips(
            clips, methods, colmap=colmap, tracker=tracker, max_size=max_size, fps=fps, max_frames=max_frames,
            colmap_settings=colmap_settings, tracker_settings=tracker_settings, brightness=_modes(brightness),
            oracles=oracles, strips=strips, threads=threads, progress=progress,
            cache=ResultCache(cache_dir) if cache_dir is not None else None, content=parse_content(content),
        )  # fmt: skip


def _reference_descriptions() -> list[dict[str, Any]]:
    """The reference rows as ``EvaluationResult.methods`` entries (table order: clean, then the oracles)."""
    from ..methods.rnn import GAIN_MAX, GAIN_MIN, GAMMA_MAX, GAMMA_MIN

    what = {
        CLEAN_LABEL: "the clean frames themselves (no lighting disturbance)",
        CURVE_LABEL: "per frame, the least-squares monotone 256-entry tone curve mapping input to clean",
        GAIN_GAMMA_LABEL: "per frame, the least-squares gain and gamma (product's LUT) mapping input to clean",
        GAMMA_LABEL: "per frame, the least-squares gamma (product's LUT) mapping input to clean",
    }
    ranges = {
        GAIN_GAMMA_LABEL: {"gain_range": [GAIN_MIN, GAIN_MAX], "gamma_range": [GAMMA_MIN, GAMMA_MAX]},
        GAMMA_LABEL: {"gamma_range": [GAMMA_MIN, GAMMA_MAX]},
    }
    return [
        {
            "label": label,
            "name": label,
            "options": {},
            "parameters": {"reference": True, "description": what[label]} | ranges.get(label, {}),
            "model": None,
        }
        for label in REFERENCE_LABELS
    ]


@contextmanager
def _threads(n: int | None) -> Iterator[None]:
    import torch

    if n is None:
        yield
        return
    before = torch.get_num_threads(), cv2.getNumThreads()
    torch.set_num_threads(n)
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before[0])
        cv2.setNumThreads(before[1])


def _evaluate_clips(
    clips: Iterable[ClipRef | EvalClip],
    methods: Sequence[EvalMethod],
    *,
    colmap: bool,
    tracker: bool,
    max_size: int | None,
    fps: float,
    max_frames: int | None,
    colmap_settings: ColmapSettings | None,
    tracker_settings: TrackerSettings | None,
    brightness: tuple[str, ...],
    oracles: bool,
    strips: int,
    threads: int | None,
    progress: Progress | None,
    cache: ResultCache | None,
    content: str,
) -> EvaluationResult:
    t0 = time.perf_counter()
    colmap_settings = colmap_settings or ColmapSettings()
    built, skipped, described = build_methods(methods)
    tracker_settings = tracker_settings or TrackerSettings()
    result = EvaluationResult(methods=described, skipped_methods=skipped)
    result.settings = {
        "max_size": max_size,
        "fps": fps,
        "max_frames": max_frames,
        "threads": threads,
        "colmap": asdict(colmap_settings) if colmap else None,
        # the brightness setting is replaced by each of "brightness" below
        "tracker": {k: v for k, v in asdict(tracker_settings).items() if k != "brightness"} if tracker else None,
        "brightness": list(brightness) if tracker else [],
        "oracles": oracles,
        "content": content_setting(content),
        "dark_threshold": 0.1,
        "bright_threshold": 0.95,
    }
    for label, reason in skipped.items():
        if progress:
            progress("skipped", {"method": label, "error": reason})
    warmed = False
    for item in clips:
        name = item.name
        source = str(item.path) if isinstance(item, ClipRef) else item.source
        if progress:
            progress("clip", {"clip": name})
        try:
            clip = item.load(max_size, fps, max_frames) if isinstance(item, ClipRef) else item
            if not warmed:
                for _, m in built:
                    _warm_up(m, clip.frames)
                warmed = True
            keep = len(result.strips) < strips
            record, thumbs = evaluate_clip(
                clip,
                built,
                colmap=colmap,
                tracker=tracker,
                colmap_settings=colmap_settings,
                tracker_settings=tracker_settings,
                brightness=brightness,
                oracles=oracles,
                keep_strip=keep,
                progress=progress,
                cache=cache,
                content=content,
            )
        except Exception as exc:  # noqa: BLE001 - a clip that cannot be scored fails alone, the others go on
            error = _clip_error(source, exc)
            result.failures.append({"clip": name, "source": source, "error": error})
            if progress:
                progress("failed", {"clip": name, "error": error})
            continue
        result.clips.append(record)
        if keep:
            result.strips[clip.name] = thumbs
            result.strip_frames[clip.name] = _strip_indices(len(clip.frames))
        if progress:
            progress("done", {"clip": name, "record": record})
    if oracles:
        if any(label in c.results for c in result.clips for label in REFERENCE_LABELS):
            result.methods = _reference_descriptions() + result.methods
        else:
            for label in REFERENCE_LABELS:
                result.skipped_methods[label] = NO_CLEAN_REASON
            if progress:
                progress("skipped", {"method": ", ".join(REFERENCE_LABELS), "error": NO_CLEAN_REASON})
    result.seconds = time.perf_counter() - t0
    if cache is not None:
        result.settings["cache"] = {
            "folder": str(cache.folder),
            "reused": cache.hits,
            "computed": cache.misses,
        }
    return result


__all__ = [
    "DEFAULT_METHODS",
    "ClipRecord",
    "EvalMethod",
    "EvaluationResult",
    "MethodClipResult",
    "build_methods",
    "evaluate_clip",
    "evaluate_clips",
    "failure_breakdown",
    "input_label",
    "method_list",
    "summarize",
]
