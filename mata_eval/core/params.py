"""Declared plugin parameters: a frozen dataclass per plugin, each field with a type, a default
and a one-line doc. YAML blocks are validated against it.

Example::

    @dataclass(frozen=True)
    class Params:
        padding: float = param(2.5, "search window size relative to the target")
        model: str | None = param(None, "path to the .onnx file (or $MATA_VITTRACK_ONNX)")
        mode: Literal["fast", "exact"] = param("fast", "speed/accuracy trade-off")
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Callable, Literal, Mapping

from .errors import ConfigError

_MISSING = dataclasses.MISSING


def param(default: Any, doc: str) -> Any:
    """A dataclass field with a default and a one-line description.

    Mutable defaults (lists, dicts) are copied per instance."""
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda d=default: type(d)(d), metadata={"doc": doc})
    return dataclasses.field(default=default, metadata={"doc": doc})


@dataclasses.dataclass(frozen=True)
class ParamInfo:
    name: str
    type: str
    default: Any
    doc: str
    required: bool = False   # no default: the experiment file must give it


def describe(params_cls: type) -> list[ParamInfo]:
    """The declared parameters of a plugin, for ``mata-eval list -v`` and the README reference."""
    hints = typing.get_type_hints(params_cls)
    out = []
    for f in dataclasses.fields(params_cls):
        if f.default is not _MISSING:
            default = f.default
        elif f.default_factory is not _MISSING:  # type: ignore[misc]
            default = f.default_factory()  # type: ignore[misc]
        else:
            default = None
        out.append(ParamInfo(f.name, _type_name(hints[f.name]), default, f.metadata.get("doc", ""),
                             required=f.default is _MISSING and f.default_factory is _MISSING))  # type: ignore[misc]
    return out


def parse_key_values(items: typing.Iterable[str]) -> dict[str, Any]:
    """``KEY=VALUE`` command-line items as a mapping, each value read as YAML (kept as the raw
    string where it is not valid YAML), for :func:`build_params` to validate. The caller names
    its option in the error."""
    import yaml  # lazily: the command line's start-up stays light

    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"expected KEY=VALUE, got {item!r}")
        try:
            out[key] = yaml.safe_load(value)
        except yaml.YAMLError:
            out[key] = value
    return out


def build_params(
    params_cls: type,
    values: Mapping[str, Any],
    path: tuple[str | int, ...] = (),
    locate: Callable[[tuple[str | int, ...]], str] | None = None,
) -> Any:
    """Validate ``values`` against ``params_cls`` and return an instance.

    ``path`` is the key path of the block in the experiment file and ``locate`` turns a key path
    into ``"file:line"``, so errors point at the offending line."""
    hints = typing.get_type_hints(params_cls)
    fields = {f.name: f for f in dataclasses.fields(params_cls)}
    where = locate or (lambda p: "")
    kwargs = {}
    for key, value in values.items():
        kp = path + (key,)
        if key not in fields:
            known = ", ".join(sorted(fields)) or "(none)"
            raise ConfigError(where(kp), kp, f"unknown parameter {key!r}; this plugin takes: {known}")
        kwargs[key] = _coerce(value, hints[key], kp, where)
    missing = [n for n, f in fields.items()
               if n not in kwargs and f.default is _MISSING and f.default_factory is _MISSING]  # type: ignore[misc]
    if missing:
        raise ConfigError(where(path), path, f"missing required parameter(s): {', '.join(missing)}")
    try:
        return params_cls(**kwargs)
    except ConfigError as exc:  # a plugin's own checks that name a key path: add the line
        kp = exc.keypath or path
        raise ConfigError(where(kp), kp, exc.message) from None
    except (ValueError, TypeError) as exc:  # a plugin's own cross-field checks (__post_init__)
        raise ConfigError(where(path), path, str(exc)) from None


def _coerce(value: Any, tp: Any, kp: tuple, where: Callable) -> Any:
    def fail() -> typing.NoReturn:
        hint = ""
        if isinstance(value, str) and "float" in _type_name(tp):
            try:
                number = float(value)
            except ValueError:
                number = None
            if number is not None and math.isfinite(number):
                hint = (f"; YAML reads {value} as text (an exponent needs a dot and a sign there: "
                        f"write {number!r} or {number:.1e})")
            elif number is not None:   # YAML spells these .nan, .inf and -.inf
                spelling = ".nan" if math.isnan(number) else ".inf" if number > 0 else "-.inf"
                hint = f"; YAML reads {value} as text (write {spelling})"
        raise ConfigError(where(kp), kp, f"expected {_type_name(tp)}, got {value!r} ({type(value).__name__}){hint}")

    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, kp, where)
            except ConfigError:
                pass
        fail()
    if origin is Literal:
        if value in args:
            return value
        if isinstance(value, (int, float)) and not isinstance(value, bool) and str(value) in args:
            return str(value)   # YAML reads `opencv_port: 5.1` as a number
        raise ConfigError(where(kp), kp, f"expected one of {', '.join(map(repr, args))}, got {value!r}")
    if origin in (list, tuple, typing.Sequence) or tp in (list, tuple):
        if not isinstance(value, (list, tuple)):
            fail()
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise ConfigError(where(kp), kp, f"expected {len(args)} values ({_type_name(tp)}), got {len(value)}")
            items = [_coerce(v, a, kp + (i,), where) for i, (v, a) in enumerate(zip(value, args))]
        else:
            inner = args[0] if args else Any
            items = [_coerce(v, inner, kp + (i,), where) for i, v in enumerate(value)]
        return tuple(items) if (origin is tuple or tp is tuple) else items
    if origin in (dict, typing.Mapping) or tp in (dict,):
        if not isinstance(value, dict):
            fail()
        return dict(value)
    if tp is bool:
        if isinstance(value, bool):
            return value
        fail()
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        fail()
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        fail()
    if tp is str:
        if isinstance(value, str):
            return value
        fail()
    if isinstance(tp, type) and isinstance(value, tp):
        return value
    fail()


def unsupported_types(params_cls: type) -> list[str]:
    """``name: type`` of each parameter of ``params_cls`` whose type no experiment file value can
    be (what :func:`build_params` takes: bool, int, float, str, null, Literal, unions, lists and
    tuples of those, dicts, Any); checked when a plugin is loaded, not by the first YAML value."""
    def ok(tp: Any) -> bool:
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if tp in (Any, bool, int, float, str, type(None), list, tuple, dict) or origin is Literal:
            return True
        if origin in (typing.Union, types.UnionType, list, tuple, typing.Sequence):
            return all(a is Ellipsis or ok(a) for a in args)
        return origin in (dict, typing.Mapping)

    hints = typing.get_type_hints(params_cls)
    return [f"{f.name}: {_type_name(hints[f.name])}" for f in dataclasses.fields(params_cls)
            if not ok(hints[f.name])]


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join("null" if a is type(None) else _type_name(a) for a in args)
    if origin is Literal:
        return "one of " + ", ".join(map(repr, args))
    if origin is not None:
        inner = ", ".join("..." if a is Ellipsis else _type_name(a) for a in args)
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]"
    return getattr(tp, "__name__", str(tp))
