"""Enhancement methods behind one interface (:class:`Method`), created by name.

Each method lives in its own module and is imported only when asked for, so that using ``none`` never loads torch
weights and a baseline's dependencies stay out of the common path.
"""

from __future__ import annotations

import importlib
from typing import Any

from ..errors import OptionError, load_failure_cause
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


#: Every method's name, whether or not its implementation loads here.
METHOD_NAMES: tuple[str, ...] = tuple(_REGISTRY)


def _load(name: str) -> type[Method]:
    module_name, _, class_name = _REGISTRY[name].partition(":")
    return getattr(importlib.import_module(module_name), class_name)  # type: ignore[no-any-return]


def method_problem(name: str) -> str | None:
    """Why ``name`` cannot be used here, as one line, or None when it can (imports that method's module only).

    An unknown name and an implementation that does not load are told apart: under a memory limit torch's
    libraries fail to map, and "unknown method 'rnn'" sent the user to check a name that was right.
    """
    if name not in _REGISTRY:
        return f"unknown method {name!r}; available: {', '.join(available_methods())}"
    try:
        _load(name)
    except (ImportError, AttributeError, MemoryError, OSError) as exc:
        return f"method {name!r} cannot be loaded here: {load_failure_cause(exc)}"
    return None


def is_available(name: str) -> bool:
    """True if ``name`` is a known method whose implementation imports; imports that method's module only."""
    return name in _REGISTRY and method_problem(name) is None


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


__all__ = [
    "METHOD_NAMES",
    "FrameResult",
    "Method",
    "MethodStream",
    "available_methods",
    "create_method",
    "is_available",
    "method_problem",
]
