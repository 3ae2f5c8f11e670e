"""The recurrent gamma network of Zhang et al. (IPMI 2021), layer for layer as in the authors' release.

Per frame: conv3x3(3->32) + BatchNorm + ReLU -> ConvLSTM cell (hidden 32, forget-gate bias +1) -> conv3x3(32->32)
+ ReLU -> global average pool -> linear(32->1) + ReLU = ``a``. The frame is corrected as ``I ** (1/a)``, so the
gamma applied is ``1/a``. Attribute names match the release's state-dict keys (``in_cnv``, ``bn``,
``RNNcell.conv``, ``rnn_cnv``, ``out_linear``) so its checkpoint loads as it is.

Three heads share that backbone (see :mod:`colonlight.correction` for what their outputs mean):

* ``gamma`` (the paper's, the authors' checkpoint): ``linear(32->1) + ReLU = a``, gamma ``1/a``;
* ``gain-gamma`` (colonlight's default model in sessions 8-18): ``linear(32->2)``, raw outputs mapped to a gain
  and a gamma, so the correction ``gain * I ** gamma`` can undo a gain jump and a tone-curve change at once,
  which one gamma cannot;
* ``curve`` (colonlight's default model since session 19): ``linear(32->8)``, the slopes of a monotone tone
  curve per frame (``correction``), the family of the per-frame oracle curve.

Five inputs (``INPUT_CHANNELS``), the first convolution's only difference (``delta`` also changes the head's
meaning):

* ``rgb`` (the paper's, every shipped model before session 14's);
* ``rgb-log``: the frame beside its log intensity scaled to [0, 1] (``log_channels``). In log space a gain change
  is the same shift at every pixel and a gamma change a scale, whereas a scene that brightens (a wall coming
  near) shifts some pixels more than others: the first convolution sees that difference directly instead of
  having to build a logarithm from ReLUs;
* ``rgb-prev``: the frame beside the same frame corrected by the previous frame's outputs (identity before the
  first), which the state then carries as a third tensor. Consistent lighting means the last correction still
  fits unless the camera changed; this shows the network what keeping it would give, rather than leaving it to
  infer its own last output from its memory. ``gain-gamma`` and ``curve`` heads only (their zero output is the
  identity; the gamma head's is not a correction).
* ``delta``: the frame under the previous frame's correction beside its difference from the previous output
  frame (``DELTA_SCALE`` x (last output - frame under the last correction), zero before the first), both at the
  network's size; the head predicts a *change* of the last correction (``z = z_last + out``) instead of a
  correction. The relative objective asks that the camera's look at the start be kept; this makes keeping it the
  structure rather than a memory task: zero outputs keep the last correction, and where the camera did not
  change the difference is motion alone. The state carries ``z_last`` and the last output frame (``y_last``);
  an all-zero ``y_last`` (the zero state an ONNX host starts with) means "no previous frame". Same heads as
  ``rgb-prev``. The shipped default's input since session 14 (README, the default model).
* ``delta-rank``: ``delta`` plus one constant plane, ``RANK_SCALE x (1 - gamma)``, ``gamma`` being Goodman and
  Kruskal's rank correlation of the green thumbnails (``RANK_GRID``) of the frame under the last correction and
  the last output (``rank_change``). A change of lighting keeps the pixels' brightness order (a monotone curve)
  and a change of the scene (a wall coming near, a fold filling the view) does not, so the plane tells the network
  which of the two made the frame brighter; without it, it takes the scene's own brightening for an exposure
  change (README, session 26). Same state and heads as ``delta``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from .correction import CURVE_SEGMENTS, apply_head
from .errors import OptionError

HIDDEN = 32
BN_MOMENTUM = 0.01
FORGET_BIAS = 1.0

#: ``(h, c)`` of the ConvLSTM; ``rgb-prev`` networks add the previous frame's head outputs, ``delta`` networks
#: those and the previous output frame.
State = tuple[Tensor, ...]
#: Head name -> number of outputs of ``out_linear``.
HEAD_OUTPUTS = {"gamma": 1, "gain-gamma": 2, "curve": CURVE_SEGMENTS}
#: Input name -> channels ``in_cnv`` reads.
INPUT_CHANNELS = {"rgb": 3, "rgb-log": 6, "rgb-prev": 6, "delta": 6, "delta-rank": 7}
#: The ``delta`` input's difference channels are scaled up by this.
DELTA_SCALE = 8.0
#: Inputs that carry the last correction in the state (their head's zero output must be the identity).
CARRIES_CORRECTION = ("rgb-prev", "delta", "delta-rank")
#: Inputs whose head changes the last correction and whose state carries the last output frame.
REFINES_CORRECTION = ("delta", "delta-rank")
#: The ``delta-rank`` plane is this times ``1 - gamma`` (0 for an unchanged order, 2 for a reversed one). Large:
#: Adam moves each weight by about the same step, so at 4 the plane's weights (zero at the start of a fine-tune)
#: stayed near zero after an epoch; at 16 they do too (README, session 28: the network does not take the cue up).
RANK_SCALE = 16.0
#: The rank correlation (``rank_change``) reads every ``(side // RANK_GRID)``-th pixel: 16 to 31 a side, so at
#: most about 1000 samples and half a million pairs, whatever the network's size.
RANK_GRID = 16
#: The darkest level the log channels tell apart (one 8-bit step); darker samples read as it.
LOG_FLOOR = 1.0 / 255.0


def log_channels(frame: Tensor) -> Tensor:
    """``log(I)`` mapped so that ``LOG_FLOOR -> 0`` and ``1 -> 1`` (same shape as ``frame``)."""
    return 1.0 - torch.log(frame.clamp_min(LOG_FLOOR)) / math.log(LOG_FLOOR)


def rank_change(a: Tensor, b: Tensor) -> Tensor:
    """``1 - gamma``, Goodman and Kruskal's rank correlation of the green channels of ``a`` and ``b``
    (``(B, 3, H, W)``), sampled every ``H // RANK_GRID`` rows and ``W // RANK_GRID`` columns (a fixed stride, so any
    host samples the same pixels) -> ``(B,)``; 1 where either is flat.

    Green, not a grey mix: a tone curve or a gain applied to each channel keeps each channel's order exactly, not a
    mix's. ``gamma`` is ``(concordant - discordant) / (concordant + discordant)`` over the pairs of pixels, pairs
    tied in either frame left out: a curve that clips pixels (ties) keeps the order of the rest, so it still reads
    as no change, and no tie depends on the order a sort happens to pick (Kendall's tau without ties)."""
    sy = max(1, a.shape[2] // RANK_GRID)
    sx = max(1, a.shape[3] // RANK_GRID)
    ga = a[:, 1, ::sy, ::sx].flatten(1)
    gb = b[:, 1, ::sy, ::sx].flatten(1)
    agree = torch.sign(ga[:, :, None] - ga[:, None, :]) * torch.sign(gb[:, :, None] - gb[:, None, :])
    return 1.0 - agree.sum(dim=(1, 2)) / agree.abs().sum(dim=(1, 2)).clamp_min(1.0)


class ConvLSTMCell(nn.Module):
    """A convolutional LSTM cell: one 3x3 conv over ``[x, h]`` gives the gates i, f, o, g (in that order)."""

    def __init__(self, in_channels: int = HIDDEN, hidden: int = HIDDEN, kernel: int = 3) -> None:
        super().__init__()
        self.hidden = hidden
        self.conv = nn.Conv2d(in_channels + hidden, 4 * hidden, kernel, padding=kernel // 2)

    def forward(self, x: Tensor, state: tuple[Tensor, Tensor] | None) -> tuple[Tensor, Tensor]:
        """One step. ``x``: ``(B, C, H, W)``; ``state``: ``(h, c)`` or ``None`` (zeros) -> new ``(h, c)``."""
        if state is None:
            zeros = x.new_zeros(x.shape[0], self.hidden, x.shape[2], x.shape[3])
            state = (zeros, zeros)
        h, c = state
        i, f, o, g = torch.split(self.conv(torch.cat([x, h], dim=1)), self.hidden, dim=1)
        c = torch.sigmoid(f + FORGET_BIAS) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        return h, c


class GammaNet(nn.Module):
    """Predicts one ``a`` per frame (gamma = 1/a) from the frame and a recurrent state; 84,097 parameters.

    Example::

        net = GammaNet().eval()
        state = None
        for frame in clip:                   # frame: (1, 3, H, W) float in [0, 1]
            a, state = net.step(frame, state)
    """

    def __init__(self, hidden: int = HIDDEN, head: str = "gamma", inputs: str = "rgb") -> None:
        super().__init__()
        if head not in HEAD_OUTPUTS:
            raise OptionError(f"unknown head {head!r}; choose from {', '.join(HEAD_OUTPUTS)}")
        if inputs not in INPUT_CHANNELS:
            raise OptionError(f"unknown inputs {inputs!r}; choose from {', '.join(INPUT_CHANNELS)}")
        if inputs in CARRIES_CORRECTION and head == "gamma":
            raise OptionError(f"inputs {inputs!r} needs the gain-gamma or curve head (zero outputs are their identity)")
        self.head = head
        self.inputs = inputs
        self.in_cnv = nn.Conv2d(INPUT_CHANNELS[inputs], hidden, 3, padding=1)
        self.bn = nn.BatchNorm2d(hidden, momentum=BN_MOMENTUM)
        self.RNNcell = ConvLSTMCell(hidden, hidden, 3)  # noqa: N815 - the release's key name
        self.rnn_cnv = nn.Conv2d(hidden, hidden, 3, padding=1)
        self.out_linear = nn.Linear(hidden, HEAD_OUTPUTS[head])
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """The release's initialisation: Xavier-normal convs, BatchNorm weight ~ N(1, 0.02), bias 0."""
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.xavier_normal_(m.weight)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.normal_(m.weight, 1.0, 0.02)
                nn.init.zeros_(m.bias)
        if self.head != "gamma":
            # start at the identity correction (gain 1, gamma 1) with a zero output layer: a random one maps the
            # features to noise, and the quickest way for training to remove that noise is to kill the features
            # (seen: every ReLU of the backbone dead within an epoch); from zero, the first steps learn which
            # features predict the correction instead
            nn.init.zeros_(self.out_linear.weight)
            nn.init.zeros_(self.out_linear.bias)

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the tensors of ``State``, in order (what an ONNX host feeds back from frame to frame)."""
        if self.inputs in REFINES_CORRECTION:
            return ("h", "c", "z_last", "y_last")
        return ("h", "c", "z_last") if self.inputs == "rgb-prev" else ("h", "c")

    def inputs_for_head(self, head: str) -> str:
        """The input a network with ``head`` started from this one reads: this one's, unless ``head`` cannot
        read it (the paper's one-gamma head has no identity output for an input that carries a correction), then
        the paper's RGB."""
        return "rgb" if head == "gamma" and self.inputs in CARRIES_CORRECTION else self.inputs

    def step(self, frame: Tensor, state: State | None = None) -> tuple[Tensor, State]:
        """One frame. ``frame``: ``(B, 3, H, W)`` in [0, 1] -> the head's output and the new state.

        Head ``gamma``: ``a`` of shape ``(B,)`` (gamma ``1/a``); ``gain-gamma``: raw ``(B, 2)`` outputs.
        """
        cell = (state[0], state[1]) if state is not None else None
        last = None
        if self.inputs in CARRIES_CORRECTION:
            last = state[2] if state is not None else frame.new_zeros(frame.shape[0], HEAD_OUTPUTS[self.head])
        x = self._first_input(frame, state, last)
        x = torch.relu(self.bn(self.in_cnv(x)))
        h, c = self.RNNcell(x, cell)
        x = torch.relu(self.rnn_cnv(h))
        z = self.out_linear(x.mean(dim=(2, 3)))
        if self.head == "gamma":
            return torch.relu(z)[:, 0], (h, c)
        if self.inputs in REFINES_CORRECTION and last is not None:
            z = last + z
            return z, (h, c, z, apply_head(frame, z, self.head))
        return z, ((h, c, z) if self.inputs == "rgb-prev" else (h, c))

    def _first_input(self, frame: Tensor, state: State | None, last: Tensor | None) -> Tensor:
        """What ``in_cnv`` reads for ``frame`` (``INPUT_CHANNELS``); ``last``: the previous head outputs."""
        if self.inputs == "rgb-log":
            return torch.cat([frame, log_channels(frame)], dim=1)
        if last is None:
            return frame
        kept = apply_head(frame, last, self.head)
        if self.inputs == "rgb-prev":
            return torch.cat([frame, kept], dim=1)
        shown = state[3] if state is not None else torch.zeros_like(frame)
        seen = (shown.flatten(1).amax(dim=1) > 0).to(frame.dtype)[:, None, None, None]  # 0: no previous frame
        planes = [kept, DELTA_SCALE * seen * (shown - kept)]
        if self.inputs == "delta-rank":
            change = RANK_SCALE * seen[:, 0, 0, 0] * rank_change(kept, shown)
            planes.append(change[:, None, None, None].expand(-1, 1, frame.shape[2], frame.shape[3]))
        return torch.cat(planes, dim=1)

    def forward(self, frames: Tensor) -> Tensor:
        """A batch of sequences: ``(B, T, 3, H, W)`` in [0, 1] -> outputs ``(B, T)`` (``gamma`` head) or
        ``(B, T, 2)``, state from zero."""
        if frames.ndim != 5 or frames.shape[2] != 3:
            raise ValueError(f"expected (B, T, 3, H, W), got {tuple(frames.shape)}")
        state: State | None = None
        out = []
        for t in range(frames.shape[1]):
            a, state = self.step(frames[:, t], state)
            out.append(a)
        return torch.stack(out, dim=1)


def parameter_count(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
