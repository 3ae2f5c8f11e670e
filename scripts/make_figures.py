"""Regenerate the README's figures: a before/after strip and the gamma-over-time plot.

    python scripts/make_figures.py            # needs the `docs` extra (matplotlib)

A held-out synthetic clip (settings never used in training, seed 20210628, with lighting disturbances and two
undisturbed seed frames) is enhanced by the default model; the plot shows the gamma per frame (for a curve or
gain-gamma head, the summary gamma its records give) beside the recorded contrast exponent, and the mean
luminance of the input, enhanced and clean frames.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from colonlight import create_method, iter_enhanced  # noqa: E402
from colonlight.metrics import content_masks, mean_luma  # noqa: E402
from colonlight.synth import SynthConfig, generate_clip  # noqa: E402

DOCS = Path(__file__).resolve().parents[1] / "docs"
SEED = 20210628


def main() -> None:
    cfg = SynthConfig.sample(
        np.random.default_rng(SEED), split="heldout", width=320, height=256, n_frames=90, undisturbed_seeds=True
    )
    frames = list(generate_clip(cfg, seed=SEED))
    images = [f.image for f in frames]
    method = create_method("rnn", device="cpu")
    head = method.parameters().get("head", "gamma")
    results = list(iter_enhanced(iter(images), method))
    enhanced = [r.frame for r in results]
    gammas = [r.gamma for r in results]
    # with tone matching on, the table applied is the network's curve pulled toward the last frame's tones
    applied = [r.info.get("applied_gamma", r.gamma) for r in results]
    matched = any("applied_gamma" in r.info for r in results)

    picks = np.linspace(4, len(images) - 1, 6).astype(int)
    rows = [
        np.hstack([images[i] for i in picks]),
        np.hstack([enhanced[i] for i in picks]),
        np.hstack([frames[i].clean for i in picks]),
    ]
    labels = ["as recorded", "enhanced (colonlight)", "clean (fixed exposure)"]
    strip = []
    for label, row in zip(labels, rows, strict=True):
        bar = np.full((22, row.shape[1], 3), 30, np.uint8)
        cv2.putText(bar, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (235, 235, 235), 1, cv2.LINE_AA)
        strip += [bar, row]
    DOCS.mkdir(exist_ok=True)
    cv2.imwrite(str(DOCS / "before_after.png"), cv2.cvtColor(np.vstack(strip), cv2.COLOR_RGB2BGR))

    masks = content_masks(images)
    t = np.arange(len(images)) / cfg.fps
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    gamma_label = "gamma applied by colonlight" if head == "gamma" else f"colonlight's gamma ({head} head: summary)"
    ax1.plot(t, gammas, color="tab:blue", label=gamma_label)
    if matched:
        ax1.plot(t, applied, color="tab:purple", lw=1, label="after tone matching (summary of the table applied)")
    contrast = [f.lighting.get("contrast", 1.0) for f in frames]
    ax1.plot(t, contrast, color="tab:orange", ls="--", label="recorded contrast exponent")
    ax1.set_ylabel("exponent")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.plot(t, mean_luma(images, masks), color="0.4", label="input")
    ax2.plot(t, mean_luma(enhanced, masks), color="tab:blue", label="enhanced")
    ax2.plot(t, mean_luma([f.clean for f in frames], masks), color="tab:green", ls=":", label="clean")
    ax2.set_ylabel("mean luminance")
    ax2.set_xlabel("time (s)")
    ax2.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"held-out synthetic clip (seed {SEED}): per-frame gamma and luminance")
    fig.tight_layout()
    fig.savefig(DOCS / "gamma_plot.png", dpi=110)
    print(f"wrote {DOCS / 'before_after.png'} and {DOCS / 'gamma_plot.png'}")


if __name__ == "__main__":
    main()
