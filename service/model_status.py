"""The default model's state (loading, ready, failed), and its loading at start-up in a thread of its own, so
that the server answers ``/healthz`` and ``/readyz`` while torch and the weights load."""

from __future__ import annotations

import gc
import json
import logging
from typing import Any

from colonlight import MethodSpec, network_threads

from .runners import MethodCache

log = logging.getLogger("colonlight.service")


class ModelStatus:
    """``state`` is ``loading``, ``ready`` or ``failed`` (with ``message`` saying why); ``info`` describes the
    loaded method (``/readyz``, ``/v1/info``)."""

    def __init__(self) -> None:
        self.state = "loading"  # loading | ready | failed
        self.message = "loading the model"
        self.info: dict[str, Any] | None = None

    def fail(self, message: str) -> None:
        self.state, self.message = "failed", message

    def load(self, methods: MethodCache, spec: MethodSpec, torch_threads: int) -> None:
        """Pin the default method in ``methods``; the process-wide tuning of the server happens here, once: torch's
        thread count, then the model and libraries frozen out of the cyclic GC's sight (later collections skip
        them)."""
        try:
            import torch

            torch.set_num_threads(torch_threads)
            method = methods.pin(spec)
            self.info = {"method": method.name, "model": method.model_info(), "parameters": method.parameters()}
            gc.collect()
            gc.freeze()  # the model and libraries are permanent: later collections skip them
            self.state, self.message = "ready", "model loaded"
            log.info("model ready: %s", json.dumps(self.info))
        except Exception as exc:  # noqa: BLE001 - reported by /readyz and by every submission
            self.fail(str(exc))
            log.error("the model could not be loaded: %s", exc)


def torch_threads(configured: int | None, spec: MethodSpec, workers: int) -> int:
    """torch threads of the server: ``COLONLIGHT_TORCH_THREADS``, else what a clip worker of the default method
    gets (:func:`colonlight.network_threads`: one for the recurrent net on its small copy of the frame, else each
    worker's share of the cores). Measured on the WebSocket route: one thread serves a single stream as fast as
    two on an idle machine (50 against 58 frames/s) at 23 against 34 ms of CPU a frame, and on a busy one two
    threads stalled a single stream at 1-3 frames/s where one kept 13."""
    return configured or network_threads(spec, workers)
