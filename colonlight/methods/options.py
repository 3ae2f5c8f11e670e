"""The options a user may give a method, declared once: name, type, range, default, help, the methods that take it.

Every shell is built from :data:`OPTIONS` instead of keeping its own copy: the CLI's flags (``cli/options.py``:
``--model-size``, ``--gamma``, ...), the service's request fields and its OpenAPI schema
(``service/request_options.py``) and ``colonlight evaluate``. A value is checked here, by :meth:`MethodOption.parse`,
so a bad one is refused with the same message everywhere (:class:`~colonlight.errors.MethodOptionError`), and an
option given to a method that does not take it is refused the same way (:func:`method_kwargs`).

Two scopes: a ``request`` option is the user's choice per clip (a service request may set it); a ``host`` option
is the machine's (a weights file, a device), set by a CLI flag or by the server's settings, never by a request.
The methods' other constructor arguments (CLAHE's tile grid, deflicker's window) are the Python API's only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from ..errors import MethodOptionError
from ..limits import MAX_GAMMA, MAX_MODEL_SIZE, MIN_MODEL_SIZE
from ..scene_cut import DEFAULT_SCENE_CUT
from ..tone_match import DEFAULT_TONE_MATCH

Kind = Literal["number", "size", "choice", "path", "text"]
Scope = Literal["request", "host"]
Value = str | float

#: Methods that run a network (their weights and device are options).
NETWORK_METHODS = ("rnn", "zerodce", "zerodce++")


@dataclass(frozen=True)
class MethodOption:
    """One option, as every shell shows and checks it.

    Attributes:
        name: the keyword of the methods' constructors (``model_size``); the CLI's flag is ``--model-size``,
            its environment variable ``COLONLIGHT_MODEL_SIZE``, a request's field ``model_size``.
        kind: ``number`` (a float within ``minimum``/``maximum``), ``size`` (an integer within them, or one of
            ``words``), ``choice`` (one of ``choices``), ``path`` (a file), ``text`` (checked by the method).
        methods: the methods that take it.
        help: what it does, for ``--help`` and the OpenAPI schema alike.
        default: what the methods use when it is not given (shown in the help).
        scope: ``request`` (a request may set it) or ``host`` (the CLI's flags and the server's settings only).
        always: shells pass it, with the default when none is given, to every method that takes it (the device:
            the shells' ``auto`` is not every method's own default).
        single: a value fits one method only (a weights file): a command running several methods refuses it
            unless exactly one of them takes it.
    """

    name: str
    kind: Kind
    methods: tuple[str, ...]
    help: str
    default: Value | None = None
    scope: Scope = "request"
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    choices: tuple[str, ...] = ()
    words: tuple[str, ...] = ()
    always: bool = False
    single: bool = False

    @property
    def flag(self) -> str:
        """The CLI's spelling: ``--model-size``."""
        return "--" + self.name.replace("_", "-")

    @property
    def envvar(self) -> str:
        """The environment variable the CLI (and, for a host option, the server) reads it from."""
        return "COLONLIGHT_" + self.name.upper()

    @property
    def description(self) -> str:
        """The help with the methods that take it: the same text in ``--help``, the OpenAPI schema and evaluate."""
        which = f"method {self.methods[0]} only" if len(self.methods) == 1 else f"methods {', '.join(self.methods)}"
        return f"{self.help} ({which}{'' if self.default is None else f'; default {self.default}'})"

    def range_text(self) -> str:
        """The values it accepts, in words: ``above 0 and at most 10``, ``an integer 8..1024, 'full' or 'auto'``."""
        if self.kind == "size":
            words = " or ".join(repr(w) for w in self.words)
            return f"an integer {self.minimum:g}..{self.maximum:g}" + (f", {words}" if words else "")
        if self.kind == "choice":
            return "one of " + ", ".join(self.choices)
        bounds = []
        if self.minimum is not None:
            bounds.append(f"{'above' if self.exclusive_minimum else 'at least'} {self.minimum:g}")
        if self.maximum is not None:
            bounds.append(f"at most {self.maximum:g}")
        return "a number " + " and ".join(bounds) if bounds else "a number"

    def parse(self, value: object) -> Value:
        """``value`` (text from a flag or a form, or a JSON value) checked and made canonical: a float for a
        ``number``; text for the rest (a ``size`` as ``"64"``, ``"full"`` or ``"auto"``). Raises
        :class:`MethodOptionError` naming the option, the accepted values and ``value``."""
        if self.kind in ("path", "text"):
            if not isinstance(value, str) and not hasattr(value, "__fspath__"):
                raise self._refused(value)
            return str(value)
        if self.kind == "choice":
            if value not in self.choices:
                raise self._refused(value)
            return str(value)
        if self.kind == "size":
            return self._parse_size(value)
        return self._parse_number(value)

    def _parse_size(self, value: object) -> str:
        text = str(value).strip().lower() if isinstance(value, (str, int)) and not isinstance(value, bool) else None
        if text is None:
            raise self._refused(value)
        if text in self.words:
            return text
        # isdecimal, not isdigit: a superscript "²" is a digit int() refuses (a ValueError traceback in the CLI, a
        # 422 quoting int()); and no more digits than the bound has, past which int() refuses (4300) or is slow
        significant = text.lstrip("0") or "0"
        if not text.isdecimal() or len(significant) > len(str(int(self.maximum or 0))):
            raise self._refused(value)
        if not self._within(int(significant)):
            raise self._refused(value)
        return str(int(significant))

    def _parse_number(self, value: object) -> float:
        if isinstance(value, bool) or not isinstance(value, (str, int, float)):
            raise self._refused(value)
        try:
            number = float(value)
        except (ValueError, OverflowError):  # OverflowError: an int past a float's range (a JSON 1 and 400 zeros)
            raise self._refused(value) from None
        if not math.isfinite(number) or not self._within(number):
            raise self._refused(value)
        return number

    def _within(self, number: float) -> bool:
        if self.minimum is not None and (number <= self.minimum if self.exclusive_minimum else number < self.minimum):
            return False
        return self.maximum is None or number <= self.maximum

    def _refused(self, value: object) -> MethodOptionError:
        shown = repr(value)
        if len(shown) > 60:  # a form field of 8 KB, a JSON number of 400 digits: echoed whole, a line of pages
            shown = f"{shown[:40]}... ({len(str(value))} characters)"
        return MethodOptionError(self.name, f"{self.name} must be {self.range_text()}, got {shown}")

    def not_for(self, methods: Sequence[str]) -> MethodOptionError:
        """The error for this option given to ``methods``, none of which takes it."""
        which = f"method {self.methods[0]}" if len(self.methods) == 1 else "methods " + _or(self.methods)
        return MethodOptionError(self.name, f"{self.name} applies only to {which}, not {_or(map(repr, methods))}")

    def json_schema(self) -> dict[str, Any]:
        """The OpenAPI property of a request field (a form field is text: a size is a pattern)."""
        schema: dict[str, Any] = {"description": self.description}
        if self.kind == "number":
            schema["type"] = "number"
            if self.minimum is not None:
                schema["exclusiveMinimum" if self.exclusive_minimum else "minimum"] = self.minimum
            if self.maximum is not None:
                schema["maximum"] = self.maximum
        elif self.kind == "size":
            digits = len(str(int(self.maximum or 0)))
            schema.update(type="string", pattern=f"^({'|'.join((*self.words, f'[0-9]{{1,{digits}}}'))})$")
            schema.update({"x-minimum": self.minimum, "x-maximum": self.maximum})
        elif self.kind == "choice":
            schema.update(type="string", enum=list(self.choices))
        else:
            schema["type"] = "string"
        return schema


def _or(items: Sequence[str] | Any) -> str:
    words = list(items)
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} or {words[-1]}"


OPTIONS: tuple[MethodOption, ...] = (
    MethodOption(
        "weights",
        "path",
        NETWORK_METHODS,
        "Weights file: for rnn ours (.safetensors with its .json card) or the authors' .pth; for zerodce and "
        "zerodce++ a file colonlight train wrote. Default: the installed weights.",
        scope="host",
        single=True,
    ),
    MethodOption(
        "model_size",
        "size",
        ("rnn",),
        f"Network input side in pixels ({MIN_MODEL_SIZE}..{MAX_MODEL_SIZE}), 'full' for full-resolution input (the "
        "release's way), or 'auto': the size the weights' card gives (32 for the shipped model, trained at 48).",
        default="auto",
        minimum=MIN_MODEL_SIZE,
        maximum=MAX_MODEL_SIZE,
        words=("full", "auto"),
    ),
    MethodOption(
        "tone_match",
        "number",
        ("rnn",),
        "How much of each frame's tones to pull toward the previous output frame's, 0 (off) .. 1: consecutive "
        "frames show nearly the same surface, so this cancels most of what one frame's estimate gets wrong. "
        f"Default: {DEFAULT_TONE_MATCH:g} for colonlight's own models, 0 for the paper's one-gamma models (the "
        "authors' checkpoint stays exact to its release).",
        minimum=0.0,
        maximum=1.0,
    ),
    MethodOption(
        "scene_cut",
        "number",
        ("rnn",),
        "Rank correlation of consecutive frames' thumbnails below which a frame starts the stream afresh, 0 "
        "(never) .. 1: a cut to another scene is a new clip, not a lighting change to undo (lighting changes "
        f"keep the pixels' brightness order). Default: {DEFAULT_SCENE_CUT:g} for colonlight's own models, 0 for the "
        "paper's one-gamma models (the authors' checkpoint stays exact to its release).",
        minimum=0.0,
        maximum=1.0,
    ),
    MethodOption(
        "gamma",
        "number",
        ("gamma",),
        f"The exponent: out = in ** gamma, above 0 and at most {MAX_GAMMA:g}; below 1 brightens.",
        default=0.7,
        minimum=0.0,
        exclusive_minimum=True,
        maximum=MAX_GAMMA,
    ),
    MethodOption(
        "device",
        "text",
        NETWORK_METHODS,
        "auto | cpu | cuda | cuda:N.",
        default="auto",
        scope="host",
        always=True,
    ),
    MethodOption(
        "runtime",
        "choice",
        ("rnn",),
        "Where the network step runs: torch, or onnxruntime (CPU; the export extra; measured faster on small "
        "CPUs, see the README's benchmarks).",
        default="torch",
        scope="host",
        choices=("torch", "onnxruntime"),
    ),
)

_BY_NAME = {o.name: o for o in OPTIONS}


def option(name: str) -> MethodOption:
    """The declared option called ``name`` (KeyError for an unknown name: a shell's bug, not a user's)."""
    return _BY_NAME[name]


def method_options(method: str) -> tuple[MethodOption, ...]:
    """The options ``method`` takes, in declaration order (none for an unknown method)."""
    return tuple(o for o in OPTIONS if method in o.methods)


def request_options() -> tuple[MethodOption, ...]:
    """The options a service request may set."""
    return tuple(o for o in OPTIONS if o.scope == "request")


def methods_kwargs(
    methods: Sequence[str], given: Mapping[str, object], fallback: Mapping[str, object] | None = None
) -> dict[str, dict[str, Value]]:
    """Each method's keyword options from what a user gave and what the shell falls back on.

    ``given``: values the user chose for this call (a flag on the command line, a request's field; ``None`` is
    not given); each is checked and goes to every method in ``methods`` that takes it, and one that none of them
    takes is refused. ``fallback``: values from the environment or the server's settings, used where they apply
    and ignored elsewhere. An ``always`` option falls back on its default. Raises :class:`MethodOptionError`.
    """
    values: dict[str, Value] = {}
    for name, value in (fallback or {}).items():
        if value is not None and any(m in option(name).methods for m in methods):
            values[name] = option(name).parse(value)
    for name, value in given.items():
        if value is None:
            continue
        opt = option(name)
        takers = [m for m in methods if m in opt.methods]
        if not takers:
            raise opt.not_for(methods)
        if opt.single and len(takers) > 1:
            raise MethodOptionError(
                name, f"{name} fits one method only, but {', '.join(takers)} all take it: run one of them at a time"
            )
        values[name] = opt.parse(value)
    out: dict[str, dict[str, Value]] = {}
    for method in methods:
        kwargs: dict[str, Value] = {}
        for opt in method_options(method):
            if opt.name in values:
                kwargs[opt.name] = values[opt.name]
            elif opt.always and opt.default is not None:
                kwargs[opt.name] = opt.default
        out[method] = kwargs
    return out


def method_kwargs(
    method: str, given: Mapping[str, object], fallback: Mapping[str, object] | None = None
) -> dict[str, Value]:
    """:func:`methods_kwargs` for one method: the keyword options of ``create_method(method, ...)``."""
    return methods_kwargs([method], given, fallback)[method]


__all__ = [
    "NETWORK_METHODS",
    "OPTIONS",
    "MethodOption",
    "method_kwargs",
    "method_options",
    "methods_kwargs",
    "option",
    "request_options",
]
