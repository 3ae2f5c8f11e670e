"""`python -m benchmarks model_validation` scores the shipped default when no weights are given (it once asserted)."""

from __future__ import annotations

import numpy as np

from benchmarks.model_validation import score
from colonlight.synth import SynthConfig, generate_clip


def test_validation_scores_the_shipped_default_without_weights() -> None:
    over: dict[str, object] = {"undisturbed_seeds": True, "close_occluder": "forbid"}
    cfg = SynthConfig.sample(
        np.random.default_rng([720_000, 1]), split="heldout", width=64, height=48, n_frames=8, **over
    )
    clips = [(over, cfg, list(generate_clip(cfg, 720_000)))]
    shipped = score("rnn (shipped)", None, clips)
    none = score("none", None, clips)
    assert shipped[0] == "rnn (shipped)" and len(shipped) == len(none) == 6
    psnr_in, psnr_out = (float(v) for v in shipped[1].split(" -> "))
    assert psnr_in == float(none[1].split(" -> ")[0]) and psnr_out != psnr_in  # the model ran and changed the frames
    he = score("he", None, clips, baseline="he")
    assert he[0] == "he" and he[1] != shipped[1] and he[1].split(" -> ")[0] == none[1].split(" -> ")[0]
    oracle = score("oracle-gain-gamma", None, clips)  # a ceiling row: fitted to the clean frames, so it restores
    assert oracle[0] == "oracle-gain-gamma" and float(oracle[1].split(" -> ")[1]) > psnr_in + 3
