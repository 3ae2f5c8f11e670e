"""Enhancement methods behind one interface (:class:`Method`), created by name.

Each method lives in its own module and is imported only when asked for, so that using ``none`` never loads torch
weights and a baseline's dependencies stay out of the common path.
"""

from __future__ import annotations

import importlib
from typing import Any

from ..errors import OptionError
from .base import FrameResult, Method, MethodStream

# name -> "module:Class"; the class's constructor takes the method's options as keyword arguments.
_REGISTRY: dict[str, str] = {
    "none": "colonlight.methods.identity:IdentityMethod",
    "rnn": "colonlight.methods.rnn:RecurrentGammaMethod",
    "gamma": "colonlight.methods.fixed_gamma:FixedGammaMethod",
    "he": "colonlight.methods.histogram:HistogramEqualizationMethod",
    "clahe": "colonlight.methods.histogram:ClaheMethod",
    "agcwd": "colonlight.methods.agcwd:AgcwdMethod",
    "deflicker": "colonlight.methods.deflicker:DeflickerMethod",
    "zerodce": "colonlight.methods.zerodce:ZeroDceMethod",
    "zerodce++": "colonlight.methods.zerodce:ZeroDcePlusPlusMethod",
}


def _load(name: str) -> type[Method]:
    module_name, _, class_name = _REGISTRY[name].partition(":")
    return getattr(importlib.import_module(module_name), class_name)  # type: ignore[no-any-return]


def is_available(name: str) -> bool:
    """True if ``name`` is a known method whose implementation imports; imports that method's module only."""
    if name not in _REGISTRY:
        return False
    try:
        _load(name)
    except (ImportError, AttributeError):
        return False
    return True


def available_methods() -> list[str]:
    """Names of the methods whose implementation is present, in registry order (imports every method's module)."""
    return [name for name in _REGISTRY if is_available(name)]


def create_method(name: str, **options: Any) -> Method:
    """Build the method called ``name`` with its options (unknown names raise ``ValueError``)."""
    if name not in _REGISTRY:
        raise OptionError(f"unknown method {name!r}; choose one of {', '.join(_REGISTRY)}")
    try:
        cls = _load(name)
    except (ImportError, AttributeError) as exc:
        raise OptionError(f"method {name!r} is not available in this installation: {exc}") from exc
    return cls(**options)


__all__ = ["FrameResult", "Method", "MethodStream", "available_methods", "create_method", "is_available"]
