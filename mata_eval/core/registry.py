"""Plugin discovery: every module named in the ``mata_eval`` entry-point group is imported and
registered with pluggy. Built-in plugins come in the same way as third-party ones. A module that
fails to import is recorded (name, package, error) and the others keep working.

A name ``package.module:Class`` is a class loaded directly, without packaging (quick
experiments): the module is imported from the Python path, or from the folder mata-eval runs
from, and the class must declare its ``Params`` like any plugin."""

from __future__ import annotations

import dataclasses
import functools
import importlib
import importlib.metadata as md
import os
import re
import sys
import traceback
import warnings

import pluggy

from .hooks import KINDS, PROJECT, PluginSpecs
from .params import unsupported_types


@dataclasses.dataclass(frozen=True)
class PluginEntry:
    kind: str
    name: str
    cls: type
    package: str
    description: str


@dataclasses.dataclass(frozen=True)
class LoadFailure:
    entry_point: str
    package: str
    error: str


@dataclasses.dataclass(frozen=True)
class Registry:
    plugins: dict[str, dict[str, PluginEntry]]  # kind -> name -> entry
    failures: tuple[LoadFailure, ...]

    def get(self, kind: str, name: str) -> PluginEntry:
        """The plugin ``name`` of ``kind``, or the class a ``package.module:Class`` name points to;
        KeyError says why not (for a plugin name: the names that exist)."""
        if ":" in name:
            return load_class(kind, name)
        try:
            return self.plugins[kind][name]
        except KeyError:
            known = ", ".join(sorted(self.plugins.get(kind, {}))) or "(none)"
            hint = "".join(f"; note: {f.entry_point} ({f.package}) failed to load: {f.error}"
                           for f in self.failures)    # one line, each note set off (errors print on one)
            raise KeyError(f"unknown {kind} {name!r}; available: {known}{hint}") from None

    def names(self, kind: str) -> list[str]:
        return sorted(self.plugins.get(kind, {}))


_CLASS_PATH = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*$")


def load_class(kind: str, path: str) -> PluginEntry:
    """The class named by ``package.module:Class``, as a plugin of ``kind``. KeyError says what
    is wrong with the path and what was expected."""
    expected = f"expected 'package.module:Class', a {kind} class with a Params dataclass"
    if not _CLASS_PATH.match(path):
        raise KeyError(f"{kind} {path!r} is not a class path; {expected}")
    module_name, class_name = path.split(":")
    if os.getcwd() not in sys.path:  # the folder mata-eval runs from, after everything else
        sys.path.append(os.getcwd())
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # the user's module: any error in it is reported, not raised
        last = traceback.format_exception_only(type(exc), exc)[-1].strip()
        raise KeyError(f"{kind} {path!r}: cannot import {module_name!r} ({last}); {expected}") from None
    cls = getattr(module, class_name, None)
    if cls is None:
        raise KeyError(f"{kind} {path!r}: module {module_name!r} ({module.__file__}) has no {class_name!r}; "
                       f"{expected}")
    if not isinstance(cls, type):
        raise KeyError(f"{kind} {path!r}: {class_name!r} is a {type(cls).__name__}, not a class; {expected}")
    if (problem := class_problem(kind, cls)) is not None:
        raise KeyError(f"{kind} {path!r}: class {class_name} {problem}")
    return PluginEntry(kind, path, cls, module_name, describe_line(cls))


#: the methods each kind of plugin is called through (mata_eval.core.interfaces)
METHODS = {"dataset": ("sequences",), "tracker": ("initialize", "track"),
           "egomotion": ("initialize", "estimate"), "estimator": ("initialize", "step")}


def class_problem(kind: str, cls: object) -> str | None:
    """What keeps ``cls`` from being a ``kind`` plugin, or None: a class with a ``Params``
    dataclass and the methods the framework calls (checked when it is loaded, not on the first
    frame of a run)."""
    if not isinstance(cls, type):
        return f"is a {type(cls).__name__}, not a class"
    if not dataclasses.is_dataclass(getattr(cls, "Params", None)):
        return ("has no Params dataclass (an empty one will do: @dataclass(frozen=True) class Params: "
                "pass); see README 'Writing a plugin'")
    missing = [m for m in METHODS.get(kind, ()) if not callable(getattr(cls, m, None))]
    if missing:
        return (f"has no {' or '.join(missing)} method (a {kind} plugin needs "
                f"{', '.join(METHODS[kind])}: mata_eval.core.interfaces)")
    try:
        unsupported = unsupported_types(cls.Params)
    except Exception as exc:  # an annotation that does not resolve (a name not imported)
        return f"has Params annotations that do not resolve: {exc}"
    if unsupported:
        return (f"has parameters of a type no experiment file value can be: {', '.join(unsupported)} "
                "(use bool, int, float, str, Literal, lists, tuples or dicts of these, or null)")
    return None


def describe_line(cls: type) -> str:
    doc = (cls.__doc__ or "").strip()
    return doc.splitlines()[0] if doc else ""


@functools.lru_cache(maxsize=1)
def load_registry() -> Registry:
    """Discover all plugins once per process."""
    pm = pluggy.PluginManager(PROJECT)
    pm.add_hookspecs(PluginSpecs)
    failures: list[LoadFailure] = []
    packages: dict[int, str] = {}
    for ep in sorted(md.entry_points(group=PROJECT), key=lambda e: e.name):
        package = ep.dist.name if ep.dist is not None else "?"
        try:
            module = importlib.import_module(ep.value.split(":")[0])
        except Exception as exc:  # a broken plugin must not take the others down
            last = traceback.format_exception_only(type(exc), exc)[-1].strip()
            failures.append(LoadFailure(ep.name, package, last))
            continue
        if pm.is_registered(module):
            continue
        pm.register(module, name=f"{package}:{ep.name}")
        packages[id(module)] = package

    plugins: dict[str, dict[str, PluginEntry]] = {kind: {} for kind in KINDS}
    for kind, hook_name in KINDS.items():
        hook = getattr(pm.hook, hook_name)
        for impl in hook.get_hookimpls():
            package = packages.get(id(impl.plugin), "?")
            try:
                classes = impl.function() or []
            except Exception as exc:
                failures.append(LoadFailure(impl.plugin_name, package, f"{hook_name}() raised {exc!r}"))
                continue
            for cls in classes:
                name = getattr(cls, "name", getattr(cls, "__name__", repr(cls)))
                if (problem := class_problem(kind, cls)) is not None:
                    failure: LoadFailure | None = LoadFailure(f"{kind} {name!r}", package, f"not used: it {problem}")
                else:
                    failure = _add(plugins[kind], PluginEntry(kind, name, cls, package, describe_line(cls)))
                if failure:  # also said at once: `list` is not the only place a user looks
                    failures.append(failure)
                    warnings.warn(f"plugin {failure.entry_point} of {failure.package}: {failure.error}")
    return Registry(plugins, tuple(failures))


BUILTIN = "mata-eval"


def _add(names: dict[str, PluginEntry], entry: PluginEntry) -> LoadFailure | None:
    """Register ``entry`` unless its name is taken; a built-in plugin keeps its name (a
    third-party ``kcf`` must not replace the built-in one without a word). Returns the loser."""
    old = names.get(entry.name)
    if old is None:
        names[entry.name] = entry
        return None
    keep, drop = (entry, old) if entry.package == BUILTIN and old.package != BUILTIN else (old, entry)
    names[entry.name] = keep
    return LoadFailure(f"{drop.kind} {drop.name!r}", drop.package,
                       f"not used: the name is taken by {keep.cls.__module__}.{keep.cls.__qualname__} "
                       f"[{keep.package}]; give the plugin another `name`")
