"""Unsupervised training of the gamma network with the paper's objective (no ground truth needed).

Clips are cut into ``seq_len``-frame sequences with stride ``stride`` (10 and 5 in the paper), frames resized to
``size x size``. In each sequence frames 0 and 1 are seeds. Every target frame t >= 2, corrected as ``I ** (1/a)``,
is compared with four references: the corrected frames t-1 and t-2 (a seed's corrected frame is the seed itself)
and the raw seeds 0 and 1. The loss of a target is the mean over its references of the masked mean of
``1 - SSIM``; pixels whose input intensity (mean over RGB) is above 0.7 (specular highlights) are left out.
Adam, learning rate 5e-5, batch 4, 10 epochs by default. SSIM is kornia's (Gaussian 11x11 window, sigma 1.5).

One opt-in addition, off by default (``anchor=0`` is the paper's objective exactly): ``anchor`` times the
absolute change of each target's masked mean intensity. Where the SSIM terms barely prefer a correction (a
wall that is bright because it is near, not because the exposure jumped), this tips the balance to leaving the
frame alone; where they clearly want one (a gain jump), it costs little.
"""

from __future__ import annotations

import json
import math
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from kornia.metrics import ssim as kornia_ssim
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from .atomic import atomic_path, read_json, remove_stale_temporaries, write_json_atomic
from .checkpoint import load_weights, save_weights
from .correction import apply_gain_gamma, apply_head, correct, gain_gamma_to_curve_map
from .errors import InputError, OptionError
from .limits import DEFAULT_FPS, DEFAULT_MODEL_SIZE, MAX_LEARNING_RATE, MAX_TRAIN_SEED
from .model import HEAD_OUTPUTS, INPUT_CHANNELS, GammaNet, parameter_count
from .outdir import TRAIN_LOCK, output_lock
from .sources import clip_frames

SPECULAR_THRESHOLD = 0.7
SEEDS = 2
#: Input samples at or above this are clipped by the recorder: they say nothing of the clean value.
SATURATED = 0.98
OBJECTIVES = ("paper", "restore", "relative", "hybrid")


def _check_supervised_weight(name: str, value: float, neutral: float, supervised: bool) -> None:
    """One of the supervised objective's extra weights: a multiplier (``neutral`` 1) must be above 0, an added
    term's weight (``neutral`` 0) at least 0, both finite; other than neutral only with the clean frames it needs."""
    multiplier = neutral == 1.0
    if not (math.isfinite(value) and (value > 0 if multiplier else value >= 0)):
        raise OptionError(f"{name} must be a finite number {'above 0' if multiplier else '>= 0'}, got {value!r}")
    if value != neutral and not supervised:
        raise OptionError(f"{name} needs a supervised objective (it needs the clean frames to tell)")


@dataclass
class TrainConfig:
    """Everything that determines a training run (recorded in the model card)."""

    size: int = DEFAULT_MODEL_SIZE  # train at the size inference uses
    seq_len: int = 10
    stride: int = 5
    batch: int = 4
    lr: float = 5e-5
    epochs: int = 10
    seed: int = 0
    fps: float | None = DEFAULT_FPS
    ssim_window: int = 11
    init: str | None = None  # a checkpoint to start from (fine-tuning), else fresh Xavier init
    anchor: float = 0.0  # weight of the opt-in brightness anchor; 0 is the paper's objective
    head: str = "gamma"  # "gamma" (the paper's), "gain-gamma" or "curve" (colonlight.correction)
    objective: str = "paper"  # "paper" (unsupervised) | "restore" (to clean frames) | "relative" | "hybrid"
    consistency: float = 0.5  # weight of the paper's loss inside "hybrid"
    temporal: float = 0.0  # weight of the error's frame-to-frame change inside the supervised objectives
    exposure_jitter: float = 0.0  # span of the window-constant exposure change of "relative" (0: none)
    inputs: str = "rgb"  # "rgb" (the paper's), "rgb-log", "rgb-prev", "delta" or "delta-rank" (colonlight.model)
    frame_steps: tuple[int, ...] = (1,)  # windows also of every k-th frame: motion and lighting k times as fast
    steady_weight: float = 1.0  # weight of windows whose recorded frames are their clean ones (supervised only)
    darken_weight: float = 1.0  # weight of restoration errors where the output is darker than its target
    darken_level: float = 0.0  # weight of a frame's mean output level below its target's (supervised only)

    def __post_init__(self) -> None:
        if self.objective not in OBJECTIVES:
            raise OptionError(f"objective must be one of {', '.join(OBJECTIVES)}, got {self.objective!r}")
        if self.head not in HEAD_OUTPUTS:
            raise OptionError(f"head must be one of {', '.join(HEAD_OUTPUTS)}, got {self.head!r}")
        if self.inputs not in INPUT_CHANNELS:
            raise OptionError(f"inputs must be one of {', '.join(INPUT_CHANNELS)}, got {self.inputs!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed <= MAX_TRAIN_SEED:
            raise OptionError(f"seed must be a whole number 0..{MAX_TRAIN_SEED}, got {self.seed!r}")
        if not (math.isfinite(self.lr) and 0 < self.lr <= MAX_LEARNING_RATE):
            raise OptionError(
                f"learning rate must be a finite number above 0 and at most {MAX_LEARNING_RATE:g}, got {self.lr!r}"
            )
        if self.exposure_jitter < 0 or not math.isfinite(self.exposure_jitter):
            raise OptionError(f"exposure jitter must be finite and >= 0, got {self.exposure_jitter!r}")
        steps = self.frame_steps
        if not steps or any(isinstance(k, bool) or not isinstance(k, int) or k < 1 for k in steps):
            raise OptionError(f"frame steps must be whole numbers >= 1, got {steps!r}")
        self.frame_steps = tuple(sorted(set(steps)))
        for name, value, neutral in (
            ("steady weight", self.steady_weight, 1.0),
            ("darken weight", self.darken_weight, 1.0),
            ("darken level", self.darken_level, 0.0),
        ):
            _check_supervised_weight(name, value, neutral, self.supervised)
        if self.exposure_jitter and self.objective != "relative":
            raise OptionError("exposure jitter needs --objective relative (its targets change with the input)")

    @property
    def supervised(self) -> bool:
        """The objective needs each clip's clean frames."""
        return self.objective != "paper"

    @property
    def frozen_bn(self) -> bool:
        """BatchNorm keeps its running statistics (no batch statistics) when training to restore: batch
        statistics would remove the batch's common brightness, the very thing a restoring model must see."""
        return self.supervised

    @property
    def seed_frames(self) -> int:
        """Leading frames passed through unchanged: the paper's 2, none when trained to restore every frame."""
        return SEEDS if self.objective == "paper" else 0


@dataclass
class EpochRecord:
    epoch: int
    train_loss: float
    val_loss: float | None
    seconds: float


@dataclass
class TrainResult:
    weights: Path
    card: dict[str, Any]
    history: list[EpochRecord] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # one line for each clip left out (unreadable, too short...)


def load_clip_array(path: Path, size: int, fps: float | None) -> np.ndarray:
    """All frames of one clip as ``(T, 3, size, size)`` uint8 (training data is small once resized)."""
    frames = [
        cv2.resize(f.image, (size, size), interpolation=cv2.INTER_AREA).transpose(2, 0, 1)
        for f in clip_frames(path, fps=fps)
    ]
    if not frames:
        raise InputError(f"{path}: no frames")
    return np.stack(frames)


def initial_net(cfg: TrainConfig) -> GammaNet:
    """A fresh network, or ``cfg.init``'s weights; a checkpoint with another head gives its backbone (every
    layer but the output layer), so a gain-gamma model can start from a model trained with the paper's loss. A
    curve head started from a gain-gamma checkpoint also gets its output layer, mapped to curves
    (:func:`colonlight.correction.gain_gamma_to_curve_map`): it starts with the checkpoint's corrections.

    An ``rgb`` checkpoint started as an ``rgb-log``, ``rgb-prev`` or ``delta`` network keeps its first
    convolution's RGB weights and gets zero weights for the extra channels, so the extra channels are used only as
    far as they help; ``rgb-log`` and ``rgb-prev`` start from exactly the checkpoint's corrections, ``delta`` from
    the checkpoint applied as a step-by-step refinement of its own last correction (its head changes it)."""
    if not cfg.init:
        return GammaNet(head=cfg.head, inputs=cfg.inputs)
    start = load_weights(cfg.init).net
    if start.head == cfg.head and start.inputs == cfg.inputs:
        return start
    net = GammaNet(head=cfg.head, inputs=cfg.inputs)
    state = start.state_dict()
    keep = {k: v for k, v in state.items() if not k.startswith("out_linear.") or start.head == cfg.head}
    if start.head == "gain-gamma" and cfg.head == "curve":  # start from the same corrections, as curves
        mapping = torch.from_numpy(gain_gamma_to_curve_map()).to(state["out_linear.weight"].dtype)
        keep["out_linear.weight"] = mapping @ state["out_linear.weight"]
        keep["out_linear.bias"] = mapping @ state["out_linear.bias"]
    if start.inputs != cfg.inputs:
        weight = torch.zeros_like(net.in_cnv.weight)
        shared = min(weight.shape[1], state["in_cnv.weight"].shape[1])
        weight[:, :shared] = state["in_cnv.weight"][:, :shared]
        keep["in_cnv.weight"] = weight
    net.load_state_dict(keep, strict=False)
    return net


def load_clip_pair(path: Path, cfg: TrainConfig) -> tuple[np.ndarray, np.ndarray | None]:
    """One clip's frames and, for a supervised objective, its clean frames (same shape); InputError if either
    cannot be used."""
    recorded = load_clip_array(path, cfg.size, cfg.fps)
    if not cfg.supervised:
        return recorded, None
    folder = clean_folder(path)
    if folder is None:
        raise InputError(f"{path}: objective {cfg.objective!r} needs clean frames beside the clip (clean/)")
    clean = load_clip_array(folder, cfg.size, cfg.fps)
    if clean.shape != recorded.shape:
        raise InputError(
            f"{path}: its clean frames ({folder}) do not match it frame for frame "
            f"({len(clean)} clean, {len(recorded)} recorded at --fps {cfg.fps})"
        )
    return recorded, clean


def load_sequences(
    clips: Sequence[Path], cfg: TrainConfig, on_skip: Callable[[str], None] | None = None
) -> tuple[SequenceSet, list[str]]:
    """The training windows of the usable ``clips`` (for a supervised objective, with each clip's clean frames)
    and a one-line reason for each clip left out: one unreadable video among hundreds costs that clip, not the
    run (``on_skip`` hears each reason as it is found; the model card lists them)."""
    arrays: list[np.ndarray] = []
    clean: list[np.ndarray] = []
    skipped: list[str] = []
    for path in clips:
        try:
            recorded, pair = load_clip_pair(path, cfg)
        except InputError as exc:
            skipped.append(str(exc))
            if on_skip:
                on_skip(str(exc))
            continue
        arrays.append(recorded)
        if pair is not None:
            clean.append(pair)
    sequences = SequenceSet(
        arrays,
        cfg.seq_len,
        cfg.stride,
        clean if cfg.supervised else None,
        relative=cfg.objective == "relative",
        frame_steps=cfg.frame_steps,
    )
    return sequences, skipped


def parse_frame_steps(text: str) -> tuple[int, ...]:
    """``"1,2"`` -> ``(1, 2)``; OptionError naming the text if it is not comma-separated whole numbers >= 1."""
    try:
        steps = tuple(int(part) for part in text.split(","))
    except ValueError:
        raise OptionError(f"frame steps must be comma-separated whole numbers >= 1, got {text!r}") from None
    if not steps or min(steps) < 1:
        raise OptionError(f"frame steps must be comma-separated whole numbers >= 1, got {text!r}")
    return steps


def window_starts(n_frames: int, seq_len: int, stride: int) -> list[int]:
    """Start indices of the ``seq_len``-frame windows with the given stride (clips shorter than one give none)."""
    return list(range(0, n_frames - seq_len + 1, stride))


def clean_folder(clip: Path) -> Path | None:
    """The clean frames beside a synthetic clip's recorded ones (``clip/frames`` -> ``clip/clean``), if any."""
    clip = Path(clip)
    for cand in (clip.parent / "clean", clip / "clean"):
        if cand.is_dir() and cand != clip:
            return cand
    return None


def start_curve(clean: np.ndarray, recorded: np.ndarray) -> np.ndarray:
    """The monotone 256-entry uint8 table that takes ``clean``'s levels to ``recorded``'s (histogram matching,
    over all channels): the tone change a window's first frame shows. Each level ``clean`` uses goes to the
    recorded level whose share of the cumulative histogram holds that level's middle, which is exact for any
    global monotone change (saturation included) and the identity for an undisturbed frame; levels ``clean``
    does not use are interpolated between their used neighbours (held flat beyond the ends)."""
    c_count = np.bincount(clean.ravel(), minlength=256).astype(np.float64)
    r_count = np.bincount(recorded.ravel(), minlength=256).astype(np.float64)
    used = np.flatnonzero(c_count > 0)
    if used.size == 0 or r_count.sum() == 0:
        return np.arange(256, dtype=np.uint8)
    c_mid = (np.cumsum(c_count) - c_count / 2)[used] / c_count.sum()
    r_cdf = np.cumsum(r_count) / r_count.sum()
    matched = np.minimum(np.searchsorted(r_cdf, c_mid - 1e-12, side="left"), 255)
    table = np.interp(np.arange(256), used, matched.astype(np.float64))
    out: np.ndarray = np.clip(np.rint(table), 0, 255).astype(np.uint8)
    return out


class SequenceSet:
    """The ``seq_len``-frame windows of a set of clips, held once per clip (windows overlap, frames are shared);
    with ``clean``, each clip's clean frames beside it (same shape), for the supervised objectives.

    ``relative``: the targets are the clean frames as the window's first frame shows them (each window's clean
    frames passed through ``start_curve`` of its first frame): consistency with the start, the paper's goal,
    taught with the truth. A window that starts undisturbed keeps its clean frames as targets, and a steady
    window's targets are its own frames, so a model taught this way leaves correctly lit video alone instead of
    pulling every clip to the training set's average exposure.

    ``frame_steps``: each clip also gives windows of every k-th frame for each k (the same clip seen k times as
    fast: more of the scene's own brightening per frame, which the held-out family's faster camera shows).

    ``undisturbed``: per window, with clean frames, whether its recorded frames are exactly its clean ones (a
    steady clip, or the undisturbed start of one): the windows whose right output is the input itself."""

    def __init__(
        self,
        clips: Sequence[np.ndarray],
        seq_len: int,
        stride: int,
        clean: Sequence[np.ndarray] | None = None,
        *,
        relative: bool = False,
        frame_steps: Sequence[int] = (1,),
    ) -> None:
        self.clips = [torch.from_numpy(c) for c in clips]
        self.clean = [torch.from_numpy(c) for c in clean] if clean is not None else None
        if self.clean is not None and [c.shape for c in self.clean] != [c.shape for c in self.clips]:
            raise InputError("clean frames do not match their clips frame for frame")
        if relative and clean is None:
            raise ValueError("relative targets need clean frames")
        self.seq_len = seq_len
        self.index = [
            (ci, s, k)
            for k in frame_steps
            for ci, c in enumerate(clips)
            for s in window_starts(len(c) - (seq_len - 1) * (k - 1), seq_len, stride)
        ]
        self.undisturbed: list[bool] = []
        if self.clean is not None:
            self.undisturbed = [
                torch.equal(self._window(self.clips, ci, s, k), self._window(self.clean, ci, s, k))
                for ci, s, k in self.index
            ]
        self.start_tables: list[torch.Tensor] | None = None
        if relative and clean is not None:
            self.start_tables = [
                torch.from_numpy(start_curve(clean[ci][s], clips[ci][s])).long() for ci, s, _ in self.index
            ]

    def __len__(self) -> int:
        return len(self.index)

    def batch(self, ids: Sequence[int]) -> torch.Tensor:
        """``(B, seq_len, 3, H, W)`` float in [0, 1]."""
        return self._stack(self.clips, ids)

    def clean_batch(self, ids: Sequence[int]) -> torch.Tensor:
        """The clean frames of the same windows (as their first frames show them, for ``relative``)."""
        if self.clean is None:
            raise ValueError("this set has no clean frames")
        if self.start_tables is None:
            return self._stack(self.clean, ids)
        seqs = []
        for i in ids:
            ci, s, k = self.index[i]
            seqs.append(self.start_tables[i][self._window(self.clean, ci, s, k).long()])
        return torch.stack(seqs).float().div_(255.0)

    def window_weights(self, ids: Sequence[int], steady_weight: float) -> torch.Tensor | None:
        """``(B,)``: ``steady_weight`` for the undisturbed windows among ``ids``, 1 for the others (None when
        every weight would be 1)."""
        if steady_weight == 1.0 or not self.undisturbed:
            return None
        return torch.tensor([steady_weight if self.undisturbed[i] else 1.0 for i in ids])

    def _window(self, clips: list[torch.Tensor], ci: int, s: int, k: int) -> torch.Tensor:
        return clips[ci][s : s + (self.seq_len - 1) * k + 1 : k]

    def _stack(self, clips: list[torch.Tensor], ids: Sequence[int]) -> torch.Tensor:
        seqs = [self._window(clips, ci, s, k) for ci, s, k in (self.index[i] for i in ids)]
        return torch.stack(seqs).float().div_(255.0)


def unclipped(frames: torch.Tensor) -> torch.Tensor:
    """1.0 where the recorder did not clip the sample (a clipped sample says nothing of its clean value)."""
    return (frames < SATURATED).float()


def restore_loss(
    frames: torch.Tensor,
    clean: torch.Tensor,
    out: torch.Tensor,
    head: str,
    corrected: torch.Tensor | None = None,
    weights: torch.Tensor | None = None,
    darken_weight: float = 1.0,
) -> torch.Tensor:
    """Mean absolute difference between the corrected frames and the clean ones, over the samples the recorder
    did not clip. Every frame is a target: a model trained this way corrects from the first frame on (no seed
    frames). ``corrected``: ``apply_head(frames, out, head)`` when the caller already has it; ``weights``:
    ``(B,)``, each window's samples count that many times in the mean; ``darken_weight``: a sample corrected
    darker than its target costs that many times its error (above 1, where the model cannot tell a scene's own
    brightening from the camera's it leans towards leaving it: the median becomes a higher quantile)."""
    if corrected is None:
        corrected = apply_head(frames, out, head)
    keep = unclipped(frames)
    if weights is not None:
        keep = keep * weights.to(keep)[:, None, None, None, None]
    error = corrected - clean
    cost = error.abs()
    if darken_weight != 1.0:
        cost = torch.where(error < 0, cost * darken_weight, cost)
    return (cost * keep).sum() / keep.sum().clamp_min(1.0)


def temporal_restore_loss(
    frames: torch.Tensor,
    clean: torch.Tensor,
    out: torch.Tensor,
    head: str,
    corrected: torch.Tensor | None = None,
    weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Mean over consecutive frames of |change of the mean brightness error| (corrected minus clean, over the
    samples unclipped in both frames). A per-frame L1 leaves the model free to guess each frame's level
    independently, and independent guesses flicker; this term asks that whatever error remains stays the same
    from frame to frame, so the output flickers as the clean frames do and no more. ``weights``: ``(B,)``, as
    for ``restore_loss`` (a weighted mean over windows)."""
    if frames.shape[1] < 2:
        return frames.new_zeros(())
    if corrected is None:
        corrected = apply_head(frames, out, head)
    error = corrected - clean
    keep = unclipped(frames)
    both = keep[:, 1:] * keep[:, :-1]
    dims = (2, 3, 4)
    denom = both.sum(dim=dims).clamp_min(1.0)
    now = (error[:, 1:] * both).sum(dim=dims) / denom
    before = (error[:, :-1] * both).sum(dim=dims) / denom
    change = (now - before).abs().mean(dim=1)
    if weights is None:
        return change.mean()
    w = weights.to(change)
    return (change * w).sum() / w.sum()


def darken_level_loss(
    frames: torch.Tensor,
    clean: torch.Tensor,
    corrected: torch.Tensor,
    weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Mean over frames of how far the frame's mean level falls below its target's (0 where it does not), over
    the samples the recorder did not clip. Unlike ``darken_weight`` it leaves the per-sample term symmetric: only
    the level is pushed up where the model is unsure, not every tone. ``weights``: ``(B,)``, as for
    ``restore_loss``."""
    keep = unclipped(frames)
    dims = (2, 3, 4)
    error = ((corrected - clean) * keep).sum(dim=dims) / keep.sum(dim=dims).clamp_min(1.0)
    below = torch.relu(-error).mean(dim=1)
    if weights is None:
        return below.mean()
    w = weights.to(below)
    return (below * w).sum() / w.sum()


def paper_loss_any_head(frames: torch.Tensor, out: torch.Tensor, head: str, window: int, anchor: float) -> torch.Tensor:
    """The paper's loss for either head (``sequence_loss`` takes ``a``; the gain-gamma head's frames are
    corrected first and compared the same way)."""
    if head == "gamma":
        return sequence_loss(frames, out, window, anchor)
    return corrected_sequence_loss(frames, apply_head(frames, out, head), window, anchor)


def sequence_loss(frames: torch.Tensor, a: torch.Tensor, window: int = 11, anchor: float = 0.0) -> torch.Tensor:
    """The paper's loss for a batch of sequences. ``frames``: ``(B, T, 3, H, W)``; ``a``: ``(B, T)``.

    ``anchor > 0`` adds ``anchor * |masked mean(corrected target) - masked mean(raw target)|`` per target (see
    the module docstring); 0 leaves the paper's loss unchanged.
    """
    if frames.shape[1] <= SEEDS:
        raise ValueError(f"sequences need more than {SEEDS} frames, got {frames.shape[1]}")
    return corrected_sequence_loss(frames, correct(frames, a), window, anchor)


def corrected_sequence_loss(
    frames: torch.Tensor, corrected: torch.Tensor, window: int = 11, anchor: float = 0.0
) -> torch.Tensor:
    """The paper's loss given the corrected frames ``(B, T, 3, H, W)`` (their seeds are replaced by the raw
    seeds, which are written unchanged)."""
    t = frames.shape[1]
    if t <= SEEDS:
        raise ValueError(f"sequences need more than {SEEDS} frames, got {t}")
    out = torch.cat([frames[:, :SEEDS], corrected[:, SEEDS:]], dim=1)  # seeds are written unchanged
    losses = []
    for k in range(SEEDS, t):
        target = out[:, k]
        keep = (frames[:, k].mean(dim=1, keepdim=True) <= SPECULAR_THRESHOLD).float()
        denom = keep.sum(dim=(1, 2, 3)).clamp_min(1.0) * 3
        ref_losses = []
        for ref in (out[:, k - 1], out[:, k - 2], frames[:, 0], frames[:, 1]):
            dissim = 1.0 - kornia_ssim(ref, target, window, max_val=1.0)
            ref_losses.append((dissim * keep).sum(dim=(1, 2, 3)) / denom)
        target_loss = torch.stack(ref_losses).mean(dim=0)
        if anchor:
            shift = ((target - frames[:, k]) * keep).sum(dim=(1, 2, 3)) / denom
            target_loss = target_loss + anchor * shift.abs()
        losses.append(target_loss)
    return torch.stack(losses).mean()


def exposure_changes(n: int, span: float, rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` random ``(gain, gamma)`` pairs: ``log gain`` uniform in ``[-span, span]``, ``log gamma`` in half that."""
    log_gain = rng.uniform(-span, span, n)
    log_gamma = rng.uniform(-span / 2, span / 2, n)
    return torch.from_numpy(np.exp(log_gain)).float(), torch.from_numpy(np.exp(log_gamma)).float()


def batch_loss(
    net: GammaNet,
    data: SequenceSet,
    ids: Sequence[int],
    cfg: TrainConfig,
    anchor: float,
    exposure: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """The configured objective on one batch of windows.

    ``exposure``: per-window ``(gain, gamma)`` applied to a window's frames and to its relative targets alike
    (``min(1, gain * I ** gamma)``). The targets are relative to the window's first frame, so the right correction
    does not change, while the window's absolute brightness no longer tells the model what correction it needs:
    a model that had learned "bright frames are over-exposed" would darken correctly lit bright video, and this
    takes that cue away. (Measured, session 12: it did not reduce the darkening of steady clips; README.)"""
    x = data.batch(ids)
    clean = data.clean_batch(ids) if cfg.supervised else None
    if exposure is not None and clean is not None:
        x, clean = (apply_gain_gamma(v, exposure[0][:, None], exposure[1][:, None]) for v in (x, clean))
    out = net(x)
    if clean is None:  # the paper's objective, the one that needs no clean frames
        return paper_loss_any_head(x, out, cfg.head, cfg.ssim_window, anchor)
    corrected = apply_head(x, out, cfg.head)  # once for both terms
    weights = data.window_weights(ids, cfg.steady_weight)
    loss = restore_loss(x, clean, out, cfg.head, corrected, weights, cfg.darken_weight)
    if cfg.temporal:
        loss = loss + cfg.temporal * temporal_restore_loss(x, clean, out, cfg.head, corrected, weights)
    if cfg.darken_level:
        loss = loss + cfg.darken_level * darken_level_loss(x, clean, corrected, weights)
    if cfg.objective == "hybrid":
        loss = loss + cfg.consistency * paper_loss_any_head(x, out, cfg.head, cfg.ssim_window, anchor)
    return loss


def _evaluate(net: GammaNet, data: SequenceSet, cfg: TrainConfig) -> float | None:
    """Validation loss: the paper's loss for the paper's objective, else the objective itself (no anchor)."""
    if len(data) == 0:
        return None
    net.eval()
    total, count = 0.0, 0
    with torch.no_grad():
        for start in range(0, len(data), cfg.batch):
            ids = list(range(start, min(start + cfg.batch, len(data))))
            total += float(batch_loss(net, data, ids, cfg, 0.0)) * len(ids)
            count += len(ids)
    net.train()
    if cfg.frozen_bn:
        net.bn.eval()
    return total / count


#: Prefix of the network's tensors in a training state (the optimizer's are ``opt.<param>.<name>``).
MODEL_KEY = "model."


def _model_state(tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The network's state dict out of a training state's tensors."""
    return {k.removeprefix(MODEL_KEY): v for k, v in tensors.items() if k.startswith(MODEL_KEY)}


def _save_state(
    path: Path,
    net: GammaNet,
    opt: torch.optim.Optimizer,
    epoch: int,
    history: list[EpochRecord],
    card: dict[str, Any],
) -> None:
    """Resumable training state: tensors in safetensors, the rest in JSON (nothing pickled). ``card``: the model
    card this epoch's weights would get, so that any epoch can be exported later (``export_epoch``)."""
    tensors = {f"{MODEL_KEY}{k}": v.detach().contiguous() for k, v in net.state_dict().items()}
    opt_state = opt.state_dict()
    meta: dict[str, Any] = {
        "epoch": epoch,
        "history": [asdict(h) for h in history],
        "card": card,
        "param_groups": opt_state["param_groups"],
        "steps": {},
    }
    for pid, st in opt_state["state"].items():
        for key, val in st.items():
            if key == "step":
                meta["steps"][str(pid)] = float(val)
            else:
                tensors[f"opt.{pid}.{key}"] = val.contiguous()
    with atomic_path(path.with_suffix(".safetensors")) as tmp:
        save_file(tensors, str(tmp))
    write_json_atomic(path.with_suffix(".json"), meta)


#: What a user can do about a training state that cannot be resumed.
_STATE_HINT = "; delete it to resume from the epoch before, or give --no-resume or another --output"


def _read_state_meta(path: Path) -> dict[str, Any]:
    """The JSON half of a saved training state; InputError naming it if it cannot be read."""
    try:
        meta = read_json(path.with_suffix(".json"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path.with_suffix('.json')}: unreadable training state ({exc}){_STATE_HINT}") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path.with_suffix('.json')}: unreadable training state (not a JSON object){_STATE_HINT}")
    return meta


#: Settings a resumed run may change: the remaining epochs and their learning rate (README: "resumed to 6 at
#: --lr 5e-5"). Any other difference would make the card describe a run that never happened.
_RESUMABLE_CHANGES = frozenset({"epochs", "lr"})


def _check_resumable(path: Path, meta: dict[str, Any], cfg: TrainConfig) -> int:
    """The epoch the state at ``path`` was saved after; InputError if this run cannot continue it: the state was
    trained with other settings (a different head or input cannot even load it; a different size or objective
    would leave a card claiming settings its first epochs never had), or it has more epochs than ``cfg.epochs``
    (the weights written would be those of the later epoch, under a card saying ``cfg.epochs``)."""
    epoch = meta.get("epoch")
    if isinstance(epoch, bool) or not isinstance(epoch, int) or epoch < 1:  # -3 was a traceback from NumPy's seeding
        raise InputError(
            f"{path.with_suffix('.json')}: unreadable training state (its epoch is not a whole number >= 1: "
            f"{str(epoch)[:40]}){_STATE_HINT}"
        )
    card = meta.get("card")
    saved = card.get("training") if isinstance(card, dict) else None
    if isinstance(saved, dict):  # states saved before cards were kept in them have nothing to compare
        now = json.loads(json.dumps(asdict(cfg)))
        diffs = [
            f"--{key.replace('_', '-')} {saved[key]!r} (now {value!r})"
            for key, value in now.items()
            if key not in _RESUMABLE_CHANGES and key != "objective" and key in saved and saved[key] != value
        ]
        if not diffs and saved.get("objective", objective_text(cfg)) != objective_text(cfg):
            diffs.append(f"--objective {saved['objective']!r} (now {objective_text(cfg)!r})")
        if diffs:
            raise InputError(
                f"{path}: the run in {path.parent.parent} was trained with {', '.join(diffs)}; only --epochs and "
                "--lr may change when it resumes: rerun with its settings, or give --no-resume or another --output"
            )
    if epoch > cfg.epochs:
        raise InputError(
            f"{path}: the run in {path.parent.parent} has trained {epoch} epochs, more than --epochs {cfg.epochs}: "
            f"give --epochs {epoch} or more to go on, or --export-epoch N for the weights of an earlier epoch"
        )
    return epoch


def _load_state(path: Path, net: GammaNet, opt: torch.optim.Optimizer) -> tuple[int, list[EpochRecord]]:
    """Restore ``net`` and ``opt`` from the state at ``path``; InputError naming it if it is damaged or was saved
    by a network of another shape."""
    meta = _read_state_meta(path)
    try:
        tensors = load_file(str(path.with_suffix(".safetensors")))
        net.load_state_dict(_model_state(tensors))
        state: dict[int, dict[str, Any]] = {}
        for key, val in tensors.items():
            if key.startswith("opt."):
                _, pid, name = key.split(".", 2)
                state.setdefault(int(pid), {})[name] = val
        for pid, step in meta["steps"].items():
            state.setdefault(int(pid), {})["step"] = torch.tensor(step)
        opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
        return int(meta["epoch"]), [EpochRecord(**h) for h in meta["history"]]
    except (OSError, SafetensorError, KeyError, TypeError, ValueError, AttributeError, RuntimeError) as exc:
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        damaged = path.with_suffix(
            ".safetensors" if isinstance(exc, (OSError, SafetensorError, RuntimeError)) else ".json"
        )
        raise InputError(f"{damaged}: unreadable training state ({reason[:200]}){_STATE_HINT}") from None


def latest_state(run_dir: Path) -> Path | None:
    """The newest complete epoch state in ``run_dir/checkpoints`` (its JSON is written last): by epoch number, not
    by name, for ``epoch_1000`` sorts before ``epoch_999`` (a resume went back to epoch 999 and trained the rest
    again)."""
    states = [p for p in (run_dir / "checkpoints").glob("epoch_*.json") if p.stem.removeprefix("epoch_").isdecimal()]
    return max(states, key=lambda p: (int(p.stem.removeprefix("epoch_")), p.name)).with_suffix("") if states else None


ARCHITECTURES = {
    "gamma": "GammaNet (Zhang et al. IPMI 2021): conv-BN-ReLU, ConvLSTM(32), conv-ReLU, GAP, linear-ReLU",
    "gain-gamma": "GammaNet backbone (Zhang et al. IPMI 2021): conv-BN-ReLU, ConvLSTM(32), conv-ReLU, GAP, "
    "linear(32->2): gain and gamma (colonlight.correction)",
    "curve": "GammaNet backbone (Zhang et al. IPMI 2021): conv-BN-ReLU, ConvLSTM(32), conv-ReLU, GAP, "
    "linear(32->8): slopes of a monotone tone curve (colonlight.correction)",
}


#: What the card's architecture adds for an input other than the paper's RGB.
INPUT_TEXT = {
    "rgb": "",
    "rgb-log": "; input: RGB and its log intensity (6 channels)",
    "rgb-prev": "; input: RGB and the frame under the previous frame's correction (6 channels; state h, c, z_last)",
    "delta": "; input: the frame under the previous frame's correction and its difference from the previous output "
    "frame (6 channels; state h, c, z_last, y_last); the head's outputs change the last correction (z = z_last + out)",
    "delta-rank": "; input: the frame under the previous frame's correction, its difference from the previous "
    "output frame and a plane of 1 - the rank correlation (Goodman-Kruskal gamma) of their green thumbnails "
    "(7 channels; state h, c, z_last, y_last); the head's outputs change the last correction (z = z_last + out)",
}


def objective_text(cfg: TrainConfig) -> str:
    """The objective in words, for the model card."""
    paper = "mean over refs (t-1, t-2 corrected; seeds 0, 1 raw) of masked mean(1 - SSIM); mask: input > 0.7"
    if cfg.anchor:
        paper += f"; plus {cfg.anchor} x |masked mean shift of the target| (brightness anchor)"
    restore = f"mean |corrected - clean| over input samples below {SATURATED} (every frame a target)"
    if cfg.temporal:
        restore += f"; plus {cfg.temporal} x mean |frame-to-frame change of the mean error (corrected - clean)|"
    if cfg.steady_weight != 1.0:
        restore += (
            f"; windows whose recorded frames are exactly their clean frames (steady lighting) weigh "
            f"{cfg.steady_weight:g} x in both terms"
        )
    if cfg.darken_weight != 1.0:
        restore += f"; in the first term a sample corrected darker than its target costs {cfg.darken_weight:g} x"
    if cfg.darken_level:
        restore += f"; plus {cfg.darken_level:g} x mean over frames of how far the mean level falls below the target's"
    if cfg.objective == "paper":
        return paper
    if cfg.objective == "restore":
        return restore
    if cfg.objective == "relative":
        return restore.replace(
            "clean",
            "clean as the window's first frame shows it (clean frames through the tone change of the "
            "first frame, by histogram matching)",
            1,
        ) + (
            f"; each window's frames and targets alike through a random exposure change min(1, g * I ** k), "
            f"|log g| <= {cfg.exposure_jitter}, |log k| <= {cfg.exposure_jitter / 2}"
            if cfg.exposure_jitter
            else ""
        )
    return f"{restore}; plus {cfg.consistency} x the paper's loss ({paper})"


ProgressFn = Callable[[int, int, int, float], None]


def train_model(
    train_clips: Sequence[Path],
    val_clips: Sequence[Path],
    run_dir: Path,
    cfg: TrainConfig,
    *,
    name: str = "colonlight-rnn",
    card_extra: dict[str, Any] | None = None,
    resume: bool = True,
    on_step: ProgressFn | None = None,
    on_epoch: Callable[[EpochRecord], None] | None = None,
    on_skip: Callable[[str], None] | None = None,
) -> TrainResult:
    """Train on ``train_clips`` (videos or frame folders), validate on ``val_clips``, write
    ``run_dir/NAME.safetensors``.

    A state is saved after every epoch in ``run_dir/checkpoints``; with ``resume`` a rerun continues from the last
    one. Runs are deterministic for a given seed, data and thread count. ``on_step(epoch, step, steps, loss)``
    reports progress; a clip that cannot be used is left out, its reason passed to ``on_skip`` and kept in the
    card (``TrainResult.skipped``). The run holds ``run_dir`` (``TRAIN_LOCK``): a second run into it while this
    one trains is refused (OutputBusy) rather than overwriting this one's states and weights.
    """
    with output_lock(Path(run_dir), TRAIN_LOCK):
        return _train_model_held(
            train_clips,
            val_clips,
            Path(run_dir),
            cfg,
            name=name,
            card_extra=card_extra,
            resume=resume,
            on_step=on_step,
            on_epoch=on_epoch,
            on_skip=on_skip,
        )


def _train_model_held(
    train_clips: Sequence[Path],
    val_clips: Sequence[Path],
    run_dir: Path,
    cfg: TrainConfig,
    *,
    name: str,
    card_extra: dict[str, Any] | None,
    resume: bool,
    on_step: ProgressFn | None,
    on_epoch: Callable[[EpochRecord], None] | None,
    on_skip: Callable[[str], None] | None,
) -> TrainResult:
    """:func:`train_model` once its folder is held."""
    run_dir = Path(run_dir)
    # a run killed while saving a state or the weights left its temporary; held, nothing else writes here now
    remove_stale_temporaries(run_dir, recursive=False)
    remove_stale_temporaries(run_dir / "checkpoints", recursive=False)
    state_path = latest_state(run_dir) if resume else None
    if state_path is not None:  # before any clip is read: a state this run cannot continue fails at once
        _check_resumable(state_path, _read_state_meta(state_path), cfg)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    train_set, train_skipped = load_sequences(train_clips, cfg, on_skip)
    val_set, val_skipped = load_sequences(val_clips, cfg, on_skip)
    if len(train_set) == 0:
        if train_skipped and len(train_skipped) == len(train_clips):  # the reason is the clips', not their length
            raise InputError(
                f"no training sequences: {len(train_skipped)} of {len(train_clips)} clips could not be used "
                f"(the first: {train_skipped[0]})"
            )
        left_out = f" ({len(train_skipped)} of {len(train_clips)} clips could not be used)" if train_skipped else ""
        raise InputError(f"no training sequences: clips need at least {cfg.seq_len} frames{left_out}")

    counts: dict[str, Any] = {
        "train_clips": len(train_clips) - len(train_skipped),
        "train_sequences": len(train_set),
        "train_undisturbed_sequences": sum(train_set.undisturbed),
        "val_clips": len(val_clips) - len(val_skipped),
        "val_sequences": len(val_set),
    }
    if train_skipped or val_skipped:
        counts["skipped_clips"] = train_skipped + val_skipped
    net = initial_net(cfg)
    net.train()
    if cfg.frozen_bn:
        net.bn.eval()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    start_epoch = 0
    history: list[EpochRecord] = []
    if state_path is not None:
        start_epoch, history = _load_state(state_path, net, opt)
        for group in opt.param_groups:  # the learning rate asked for now governs the remaining epochs
            group["lr"] = cfg.lr

    steps = math.ceil(len(train_set) / cfg.batch)
    for epoch in range(start_epoch, cfg.epochs):
        t0 = time.perf_counter()
        order = np.random.default_rng(cfg.seed * 1000 + epoch).permutation(len(train_set))
        total = 0.0
        for step in range(steps):
            ids = order[step * cfg.batch : (step + 1) * cfg.batch].tolist()
            exposure = None
            if cfg.exposure_jitter:
                rng = np.random.default_rng([cfg.seed, epoch, step])
                exposure = exposure_changes(len(ids), cfg.exposure_jitter, rng)
            loss = batch_loss(net, train_set, ids, cfg, cfg.anchor, exposure)
            if not math.isfinite(loss.item()):  # stop before a NaN step: no state or weights of NaN are written
                raise OptionError(
                    f"training diverged at epoch {epoch + 1}, step {step + 1} (loss {loss.item()}): "
                    f"try a lower --lr (this run: {cfg.lr:g})"
                )
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += loss.item() * len(ids)
            if on_step:
                on_step(epoch, step + 1, steps, loss.item())
        record = EpochRecord(epoch + 1, total / len(train_set), _evaluate(net, val_set, cfg), time.perf_counter() - t0)
        history.append(record)
        card = model_card(net, cfg, name, history, counts, card_extra)
        _save_state(run_dir / "checkpoints" / f"epoch_{epoch + 1:03d}", net, opt, epoch + 1, history, card)
        if on_epoch:
            on_epoch(record)

    net.eval()
    weights_path = run_dir / f"{name}.safetensors"
    card = save_weights(net, weights_path, model_card(net, cfg, name, history, counts, card_extra))
    return TrainResult(weights=weights_path, card=card, history=history, skipped=train_skipped + val_skipped)


def model_card(
    net: GammaNet,
    cfg: TrainConfig,
    name: str,
    history: Sequence[EpochRecord],
    counts: dict[str, Any],
    card_extra: dict[str, Any] | None,
) -> dict[str, Any]:
    """The model card of a run's weights after ``history``'s epochs (``counts``: clips and windows trained and
    validated on)."""
    from . import __version__

    return {
        "name": name,
        "version": __version__,
        "architecture": ARCHITECTURES[cfg.head] + INPUT_TEXT[cfg.inputs],
        "head": cfg.head,
        "inputs": cfg.inputs,
        "seed_frames": cfg.seed_frames,
        "parameters": parameter_count(net),
        "input_size": cfg.size,
        "training": {
            **asdict(cfg),
            "objective": objective_text(cfg),
            "batchnorm": "frozen (running statistics)" if cfg.frozen_bn else "batch statistics",
            "val_loss": "the paper's loss (no anchor)" if cfg.objective == "paper" else "the objective (no anchor)",
            **counts,
            "history": [asdict(h) for h in history],
            "torch": torch.__version__,
            "python": platform.python_version(),
            **(card_extra or {}),
        },
    }


def export_epoch(run_dir: Path, epoch: int, out: Path | None = None) -> TrainResult:
    """Weights and card of epoch ``epoch`` of the run in ``run_dir`` (default ``run_dir/NAME-epochNNN``), from
    the state saved after it: model selection picks an epoch on validation clips, often not the last one.
    The card is the one the run would have written had it stopped there, with ``shipped_epoch`` set."""
    run_dir = Path(run_dir)
    state = run_dir / "checkpoints" / f"epoch_{epoch:03d}"
    if not state.with_suffix(".json").is_file():
        names = (p.stem.removeprefix("epoch_") for p in (run_dir / "checkpoints").glob("epoch_*.json"))
        saved = sorted(int(n) for n in names if n.isdecimal())
        have = f"epochs saved: {', '.join(map(str, saved))}" if saved else "no epoch saved yet"
        raise InputError(f"{run_dir}: no saved state for epoch {epoch} ({have})")
    try:
        meta = read_json(state.with_suffix(".json"))
        tensors = load_file(str(state.with_suffix(".safetensors")))
    except (OSError, ValueError, SafetensorError) as exc:
        raise InputError(f"{state}: unreadable training state ({exc})") from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("card"), dict):
        raise InputError(f"{state}.json: saved by an older colonlight, it has no model card to export")
    card = meta["card"]
    try:
        net = GammaNet(head=card["head"], inputs=card.get("inputs", "rgb"))
        net.load_state_dict(_model_state(tensors))
        history = [EpochRecord(**h) for h in meta["history"]]
        card = {**card, "training": {**card["training"], "shipped_epoch": epoch}}
        name = str(card["name"])
    except (KeyError, TypeError, OptionError, RuntimeError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{state}: its weights do not match its card ({reason[:200]})") from None
    weights_path = Path(out) if out is not None else run_dir / f"{name}-epoch{epoch:03d}.safetensors"
    card = save_weights(net.eval(), weights_path, card)
    return TrainResult(weights=weights_path, card=card, history=history)
