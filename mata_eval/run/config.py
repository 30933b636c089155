"""Experiment files: one YAML file composes dataset, tracker, egomotion, estimator, protocol,
metrics and output folder; a ``matrix:`` section expands alternatives into named runs.

Every plugin block is validated against the plugin's declared ``Params`` before anything runs,
and every error names the file, the line and the key path. Only ``yaml.safe_load`` semantics
are used (a SafeLoader; its node tree gives the line numbers).

Format (see README "Experiment files")::

    name: quickstart
    seed: 0
    output: results/quickstart
    dataset: {name: synthetic}
    occlusion: null                  # or a block of mata_eval.data.occlusion.OcclusionParams
    tracker: {name: kcf}
    egomotion: {name: grid_lk}       # or null
    estimator: {name: homography_ekf}  # or null (baseline: the tracker's output is held)
    feedback: true
    protocol: {name: eop, tracker_hz: 10}
    metrics: {profile: default}
    optional: [vittrack]             # runs with these matrix labels are skipped, with one line
                                     # saying why, when their preflight check fails
    matrix:
      mata:                          # axis: label -> overrides of top-level keys
        baseline: {egomotion: null, estimator: null}
        mata: {}
      protocol:                      # axis named after a plugin key: label -> plugin block
        ltp: {name: ltp}
        eop10: {name: eop, tracker_hz: 10}

An override block without ``name`` (or with the same name) is merged into the base block;
a block with another plugin's name replaces it.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import difflib
import functools
import hashlib
import importlib.metadata as md
import itertools
import json
import sys
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import yaml

from ..core.errors import ConfigError, raise_all
from ..core.params import build_params
from ..core.registry import Registry, load_registry
from .results import is_file_name
from .shipped import SHIPPED

PLUGIN_KEYS = ("dataset", "tracker", "egomotion", "estimator", "protocol")  # = plugin kinds
NULLABLE = {"egomotion", "estimator", "occlusion"}
TOP_LEVEL = {"name", "description", "seed", "output", "dataset", "occlusion", "tracker",
             "egomotion", "estimator", "feedback", "protocol", "metrics", "matrix", "timeout_s",
             "on_bad_frame", "optional"}
NOT_OVERRIDABLE = {"matrix", "name", "optional", "output"}   # output: one per experiment, runs are folders in it
DEFAULTS: dict[str, Any] = {"seed": 0, "egomotion": None, "estimator": None, "occlusion": None,
                            "feedback": True, "protocol": {"name": "ltp"},
                            "metrics": {"profile": "default"}, "timeout_s": 60.0, "on_bad_frame": "fail"}
BAD_FRAME_POLICIES = ("fail", "skip")
#: Experiment files hold settings, not data: larger files and alias expansions are refused
#: before anything is built from them (a 9 x 9 alias "bomb" expands to 387 million nodes).
MAX_FILE_BYTES = 1_000_000
MAX_NODES = 100_000
METRICS_KEYS = {"profile"}

KeyPath = tuple  # of str | int


@dataclasses.dataclass(frozen=True)
class PluginBlock:
    """A validated plugin block: which plugin, with which parameters."""

    kind: str
    name: str
    cls: type
    params: Any

    def create(self) -> Any:
        """A fresh instance (one per sequence, so no state leaks between sequences)."""
        return self.cls(self.params)

    @contextlib.contextmanager
    def instance(self, timeout_s: float | None = None, where: str = "") -> Iterator[Any]:
        """A fresh instance whose ``close()``, if the plugin has one (a tracker process, a
        device), runs when the ``with`` block ends, however it ends; a ``close()`` that raises
        or does not return within ``timeout_s`` (main thread) is a line on stderr naming the
        plugin and ``where`` (the results it made stand, the other runs go on)."""
        from .scheduler import CallAlarm, CallTimeout

        obj = self.create()
        try:
            yield obj
        finally:
            close = getattr(obj, "close", None)
            if callable(close):
                try:
                    CallAlarm(timeout_s).call(close)
                except (Exception, CallTimeout) as exc:   # one line (a warning showed contextlib's source line)
                    why = str(exc) if isinstance(exc, CallTimeout) else f"raised {type(exc).__name__}: {exc}"
                    print(f"warning: {self.kind} {self.name}{where}: close() {why}", file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One named run of an experiment: every block resolved and validated."""

    name: str
    seed: int
    dataset: PluginBlock
    tracker: PluginBlock
    egomotion: PluginBlock | None
    estimator: PluginBlock | None
    protocol: PluginBlock
    occlusion: Any | None
    feedback: bool
    metrics_profile: str
    resolved: dict  # the fully resolved configuration, as written to the manifest
    timeout_s: float | None = 60.0  # limit of one block call (not in the hash: results do not depend on it)
    on_bad_frame: str = "fail"  # or "skip": an unreadable frame is excluded from scoring and counted
    labels: tuple[str, ...] = ()  # its matrix labels, one per axis
    optional: bool = False  # skipped (not an error) when its preflight check fails

    @property
    def config_hash(self) -> str:
        """What the run's results depend on: its resolved configuration without the dataset's
        ``sequences`` selection (:func:`without_selection`)."""
        return _hash(without_selection(self.resolved))

    def made(self, manifest: Mapping[str, Any]) -> bool:
        """Whether a run folder's manifest records this configuration: its hash, or (a folder of
        a mata-eval that hashed the ``sequences`` selection too) its recorded configuration."""
        config = manifest.get("config")
        return manifest.get("config_hash") == self.config_hash or (
            isinstance(config, Mapping) and _hash(without_selection(config)) == self.config_hash)


def _hash(resolved: Mapping[str, Any]) -> str:
    text = json.dumps(resolved, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def without_selection(resolved: Mapping[str, Any]) -> dict[str, Any]:
    """A resolved configuration without its dataset's ``sequences`` selection: each sequence's
    result depends on that sequence alone (its seed comes from the run's seed and its name), so
    a run folder resumes, running only the new ones, when sequences are added to the list,
    removed from it (their results stay in the folder, not scored) or reordered."""
    dataset = resolved.get("dataset")
    if not isinstance(dataset, Mapping):
        return dict(resolved)
    return {**resolved, "dataset": {k: v for k, v in dataset.items() if k != "sequences"}}


def as_a_set(dataset: Mapping[str, Any]) -> dict[str, Any]:
    """A dataset block whose ``sequences`` list reads as the set of names it is: the same names
    in another order select the same data (eval's run-own-dataset test, MATA/baseline pairing)."""
    names = dataset.get("sequences")
    return {**dataset, "sequences": sorted(set(names), key=str)} if isinstance(names, list) else dict(dataset)


@dataclasses.dataclass(frozen=True)
class Experiment:
    name: str
    path: Path
    output: Path
    runs: tuple[RunSpec, ...]




def find_experiment(path: str | Path) -> Path:
    """``path`` when it is a file, else the shipped experiment of that file name (``quickstart``,
    ``experiments/quickstart.yaml`` and ``quickstart.yaml`` all name the one shipped with
    mata-eval, so the README's commands work from a wheel install outside a clone; a folder
    ``quickstart/``, a run's output, does not hide it)."""
    path = Path(path)
    if path.is_file() or path.is_absolute() or path.parent not in (Path("."), Path("experiments")):
        return path
    name = path.name if path.suffix in (".yaml", ".yml") else f"{path.name}.yaml"
    for folder in SHIPPED:
        if (folder / name).is_file():
            return folder / name
    return path


def shipped_experiments() -> list[Path]:
    """The experiment files shipped with mata-eval."""
    folder = next((f for f in SHIPPED if f.is_dir()), None)
    return sorted(folder.glob("*.yaml")) if folder else []


class _SafeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that keeps mapping keys such as ``on``/``off``/``yes`` as the strings
    the user typed (YAML 1.1 would turn matrix labels like ``off`` into ``False``)."""


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict:
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:  # before merging: a key after ``<<: *base`` overrides it
        if isinstance(key_node, yaml.ScalarNode) and key_node.tag != "tag:yaml.org,2002:merge":
            line = key_node.start_mark.line + 1
            if key_node.value in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key_node.value!r} (first on line {seen[key_node.value]}); "
                                "remove one of them", key_node.start_mark)
            seen[key_node.value] = line
    loader.flatten_mapping(node)
    out = {}
    for key_node, value_node in node.value:
        if isinstance(key_node, yaml.ScalarNode) and key_node.tag == "tag:yaml.org,2002:bool":
            key = key_node.value
        else:
            key = loader.construct_object(key_node, deep=True)
        out[key] = loader.construct_object(value_node, deep=True)
    return out


_SafeLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


class _Locator:
    """Maps key paths of the YAML document to ``file:line``."""

    def __init__(self, path: Path, root: yaml.Node | None):
        self.path = path
        self.lines: dict[KeyPath, int] = {}
        if root is not None:
            self._index(root, ())

    def _index(self, node: yaml.Node, kp: KeyPath) -> None:
        self.lines[kp] = node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            for key_node, value_node in node.value:
                key = str(key_node.value)
                self._index(value_node, kp + (key,))
                self.lines[kp + (key,)] = key_node.start_mark.line + 1
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                self._index(item, kp + (str(i),))

    def __call__(self, doc_kp: KeyPath) -> str:
        kp = tuple(str(k) for k in doc_kp)
        while kp and kp not in self.lines:
            kp = kp[:-1]
        line = self.lines.get(kp)
        return f"{self.path}:{line}" if line else str(self.path)


def _check_expansion(root: yaml.Node | None, path: Path) -> None:
    """Refuse a document whose aliases expand to more than ``MAX_NODES`` nodes, or refer to
    themselves, before anything walks or builds it (PyYAML shares aliased nodes; every later
    step would expand them). Counted with one visit per distinct node."""
    sizes: dict[int, int | None] = {}

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            if sizes[key] is None:
                raise ConfigError(f"{path}:{node.start_mark.line + 1}", (), "an alias refers to the node that holds it")
            return sizes[key]
        sizes[key] = None
        n = 1
        if isinstance(node, yaml.MappingNode):
            n += sum(size(k) + size(v) for k, v in node.value)
        elif isinstance(node, yaml.SequenceNode):
            n += sum(size(v) for v in node.value)
        if n > MAX_NODES:
            raise ConfigError(f"{path}:{node.start_mark.line + 1}", (),
                              f"aliases expand to more than {MAX_NODES} nodes; write the values out instead")
        sizes[key] = n
        return n

    if root is not None:
        size(root)


#: longest run name or matrix label: run names join the labels, and file systems stop at 255 bytes
MAX_NAME = 100


def _check_folder_name(name: str, locate: _Locator, kp: KeyPath) -> None:
    """Run names and matrix labels name folders inside the output folder: one name, no path, no
    control or Windows-reserved character, at most MAX_NAME characters."""
    if not is_file_name(name) or any(c in name for c in '<>:"|?*') or any(ord(c) < 32 for c in name) \
            or len(name) > MAX_NAME:
        raise ConfigError(locate(kp), kp, f"expected one folder name (no '/', no '..', not absolute, none of "
                                          f"<>:\"|?* or control characters, at most {MAX_NAME} characters), "
                                          f"got {name!r}: the run's results go to <output>/<name>")


def load_experiment(path: str | Path, registry: Registry | None = None) -> Experiment:
    """Read, expand and validate an experiment file (a path, or the name of a shipped one:
    :func:`find_experiment`)."""
    path = find_experiment(path)
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ConfigError(str(path), (), f"the file is {size / 1e6:.1f} MB; the limit is "
                                             f"{MAX_FILE_BYTES / 1e6:g} MB (experiment files hold settings, not data)")
        text = path.read_text(encoding="utf-8")   # YAML is UTF-8, whatever the locale says
    except UnicodeDecodeError as exc:
        raise ConfigError(str(path), (), f"not UTF-8 text (byte {exc.start}): save the experiment file as UTF-8") from None
    except OSError as exc:
        shipped = ", ".join(p.stem for p in shipped_experiments())
        raise ConfigError(str(path), (), f"cannot read experiment file: {exc.strerror}"
                          + (f" (experiments shipped with mata-eval: {shipped})" if shipped else "")) from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        _check_expansion(root, path)
        doc = yaml.load(text, Loader=_SafeLoader)  # safe: a SafeLoader with string keys
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        raise ConfigError(where, (), f"not valid YAML: {getattr(exc, 'problem', exc)}") from None
    except RecursionError:
        raise ConfigError(str(path), (), "not valid YAML: nested too deeply") from None
    locate = _Locator(path, root)
    if not isinstance(doc, dict):
        raise ConfigError(locate(()), (), "expected a mapping of experiment keys at the top level")
    for key in doc:
        if key not in TOP_LEVEL:
            raise ConfigError(locate((key,)), (key,),
                              f"unknown key; expected one of: {', '.join(sorted(TOP_LEVEL))}")
    if doc.get("name") is not None:
        _check_folder_name(str(doc["name"]), locate, ("name",))
    registry = registry or load_registry()

    base = {k: v for k, v in doc.items() if k not in ("matrix", "optional")}
    origin = {(k,): (k,) for k in base}
    optional = _optional_labels(doc, locate)
    runs = []
    errors: list[ConfigError] = []     # every run of the matrix is checked
    for label_parts, config, cfg_origin in _expand(doc, base, origin, locate):
        run_name = "-".join(label_parts) if label_parts else str(doc.get("name") or path.stem)
        try:
            spec = _resolve(run_name, config, cfg_origin, locate, registry)
        except ConfigError as exc:
            errors += getattr(exc, "errors", (exc,))   # ConfigErrors: its problems, one each
            continue
        runs.append(dataclasses.replace(spec, labels=tuple(label_parts),
                                        optional=bool(optional & set(label_parts))))
    raise_all(errors)
    names = [r.name for r in runs]
    if len({n.casefold() for n in names}) != len(names):   # one folder on a case-insensitive file system
        raise ConfigError(locate(("matrix",)), ("matrix",), f"matrix labels give duplicate run names "
                                                             f"(letter case aside): {names}")
    output = doc.get("output", f"results/{path.stem}")
    if not isinstance(output, str):
        raise ConfigError(locate(("output",)), ("output",), f"expected a folder path, got {output!r}")
    out = Path(output)
    if not out.is_absolute():
        out = Path.cwd() / out
    return Experiment(str(doc.get("name") or path.stem), path, out, tuple(runs))


def _optional_labels(doc: dict, locate: _Locator) -> set[str]:
    """The ``optional:`` list: matrix labels whose runs may be skipped."""
    value = doc.get("optional") or []
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ConfigError(locate(("optional",)), ("optional",), f"expected a list of matrix labels, got {value!r}")
    matrix = doc.get("matrix") or {}
    if not isinstance(matrix, dict):   # (checked here first: this reads the matrix before _expand)
        raise ConfigError(locate(("matrix",)), ("matrix",), "expected a mapping of axes: axis -> {label: overrides}")
    labels = {str(label) for options in matrix.values() if isinstance(options, dict) for label in options}
    unknown = [v for v in value if v not in labels]
    if unknown:
        raise ConfigError(locate(("optional",)), ("optional",),
                          f"{', '.join(map(repr, unknown))} is not a matrix label; labels: {', '.join(sorted(labels)) or '(none)'}")
    return set(value)


def _expand(doc: dict, base: dict, origin: dict, locate: _Locator):
    """Yield (labels, config, origin) for every combination of the matrix axes."""
    matrix = doc.get("matrix")
    if matrix is None:
        yield (), base, origin
        return
    if not isinstance(matrix, dict) or not matrix:
        raise ConfigError(locate(("matrix",)), ("matrix",), "expected a mapping of axes: axis -> {label: overrides}")
    axes = []
    for axis, options in matrix.items():
        kp = ("matrix", axis)
        if not isinstance(options, dict) or not options:
            raise ConfigError(locate(kp), kp, "expected a mapping of labels to overrides")
        for label in options:
            _check_folder_name(str(label), locate, kp + (label,))
        axes.append([(axis, str(label), value) for label, value in options.items()])
    for combo in itertools.product(*axes):
        config = copy.deepcopy(base)
        cfg_origin = dict(origin)
        for axis, label, value in combo:
            kp = ("matrix", axis, label)
            if axis in PLUGIN_KEYS:
                overrides = {axis: value}
                src = {axis: kp}
            else:
                if value is None:
                    value = {}
                if not isinstance(value, dict):
                    raise ConfigError(locate(kp), kp, "expected a mapping of top-level keys to override")
                overrides = value
                src = {k: kp + (k,) for k in value}
            for key, val in overrides.items():
                if key not in TOP_LEVEL - NOT_OVERRIDABLE:
                    close = difflib.get_close_matches(str(axis), PLUGIN_KEYS, n=1)
                    hint = (f" (an axis named after a plugin key takes that plugin's blocks: did you mean "
                            f"the axis {close[0]!r}?)" if close else "")
                    raise ConfigError(locate(src[key]), src[key], f"cannot override {key!r} in a matrix{hint}")
                _apply(config, cfg_origin, key, val, src[key])
        yield [label for _, label, _ in combo], config, cfg_origin


def _apply(config: dict, origin: dict, key: str, value: Any, src: KeyPath) -> None:
    old = config.get(key)
    if isinstance(old, str) and key in PLUGIN_KEYS:
        old = {"name": old}
    if isinstance(value, str) and key in PLUGIN_KEYS:
        value = {"name": value}
    merge = (isinstance(value, dict) and isinstance(old, dict)
             and value.get("name", old.get("name")) == old.get("name"))
    if merge:
        merged = dict(old)
        merged.update(value)
        config[key] = merged
        for k in value:
            origin[(key, k)] = src + (k,)
    else:
        config[key] = value
        for okp in [o for o in origin if o[:1] == (key,)]:
            del origin[okp]
        origin[(key,)] = src


def _resolve(run_name: str, config: dict, origin: dict, locate: _Locator, registry: Registry) -> RunSpec:
    def where(kp: KeyPath) -> str:
        kp = tuple(kp)
        if len(kp) == 1:   # a whole block (a plugin's cross-field check): the matrix entry that
            entries = [src[:-1] for okp, src in origin.items() if len(okp) == 2 and okp[0] == kp[0]]
            if entries:    # changed some of its keys in this run, not the base block's line
                return locate(entries[-1])
        for n in range(len(kp), 0, -1):
            if kp[:n] in origin:
                return locate(origin[kp[:n]] + kp[n:])
        return locate(kp)

    cfg = {**DEFAULTS, **config}
    for required in ("dataset", "tracker"):
        if cfg.get(required) is None:
            raise ConfigError(locate(()), (required,), f"missing required key {required!r} (a plugin block)")

    blocks: dict[str, PluginBlock | None] = {}
    resolved: dict[str, Any] = {}
    errors: list[ConfigError] = []     # every plugin block is checked: one line per problem
    for key in PLUGIN_KEYS:
        try:
            block = _plugin_block(key, cfg[key], where, registry)
        except ConfigError as exc:
            errors.append(exc)
            block = None
        blocks[key] = block
        resolved[key] = None if block is None else {"name": block.name, **dataclasses.asdict(block.params)}
    try:
        spec = _resolve_rest(run_name, cfg, where, blocks, resolved)
    except ConfigError as exc:
        errors.append(exc)
    raise_all(errors)
    return spec


def _resolve_rest(run_name: str, cfg: dict, where: Callable[[KeyPath], str], blocks: dict[str, PluginBlock | None],
                  resolved: dict[str, Any]) -> RunSpec:
    """:func:`_resolve` after the plugin blocks: plugin versions, occlusion, seed and the other
    run settings."""
    versions = {dist: v for block in blocks.values() if block is not None
                for dist, v in plugin_distribution(block.cls).items()}
    if versions:  # only then: the hash of every run of the built-in plugins stays the same
        resolved["plugin_versions"] = versions   # an upgraded plugin's results are not mixed in

    occlusion = None
    if cfg["occlusion"] is not None:
        from ..data.occlusion import OcclusionParams

        if not isinstance(cfg["occlusion"], dict):
            raise ConfigError(where(("occlusion",)), ("occlusion",), "expected a mapping of occlusion parameters or null")
        occlusion = build_params(OcclusionParams, cfg["occlusion"], ("occlusion",), where)
        resolved["occlusion"] = dataclasses.asdict(occlusion)
    else:
        resolved["occlusion"] = None

    seed = cfg["seed"]
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise ConfigError(where(("seed",)), ("seed",), f"expected an integer seed, got {seed!r}")
    if seed < 0:   # numpy's generators take seeds >= 0 (every sequence failed on -1)
        raise ConfigError(where(("seed",)), ("seed",), f"expected an integer seed >= 0, got {seed}")
    feedback = cfg["feedback"]
    if not isinstance(feedback, bool):
        raise ConfigError(where(("feedback",)), ("feedback",), f"expected true or false, got {feedback!r}")
    metrics = cfg["metrics"] or {}
    if not isinstance(metrics, dict):
        raise ConfigError(where(("metrics",)), ("metrics",), "expected a mapping like {profile: default}")
    for k in metrics:
        if k not in METRICS_KEYS:
            raise ConfigError(where(("metrics", k)), ("metrics", k),
                              f"unknown key; expected one of: {', '.join(sorted(METRICS_KEYS))}")
    profile = metrics.get("profile", "default")
    from ..core.metric_profiles import PROFILES

    if profile not in PROFILES:
        raise ConfigError(where(("metrics", "profile")), ("metrics", "profile"),
                          f"unknown metric profile {profile!r}; available: {', '.join(sorted(PROFILES))}")
    resolved.update(seed=seed, feedback=feedback, metrics={"profile": profile})
    timeout = cfg["timeout_s"]
    if timeout is not None and (isinstance(timeout, bool) or not isinstance(timeout, (int, float))
                                or not 0 < timeout < float("inf")):
        raise ConfigError(where(("timeout_s",)), ("timeout_s",),
                          f"expected seconds > 0 for one block call, or null for no limit, got {timeout!r}")
    on_bad = cfg["on_bad_frame"]
    if on_bad not in BAD_FRAME_POLICIES:
        raise ConfigError(where(("on_bad_frame",)), ("on_bad_frame",),
                          f"expected one of {', '.join(BAD_FRAME_POLICIES)}, got {on_bad!r}")
    if on_bad != "fail":  # only then: the hash of every earlier run folder stays the same
        resolved["on_bad_frame"] = on_bad
    return RunSpec(run_name, seed, blocks["dataset"], blocks["tracker"], blocks["egomotion"],
                   blocks["estimator"], blocks["protocol"], occlusion, feedback, profile, resolved,
                   None if timeout is None else float(timeout), on_bad)


def config_change(old: Any, new: Any, path: str = "") -> str | None:
    """The first difference between two resolved configurations (keys in sorted order), e.g.
    ``plugin_versions.qa-blocks: '0.1.0' then, '0.2.0' now``; None when they are the same."""
    if isinstance(old, Mapping) and isinstance(new, Mapping):
        for k in sorted(set(old) | set(new), key=str):
            if (change := config_change(old.get(k), new.get(k), f"{path}.{k}" if path else str(k))) is not None:
                return change
        return None
    if json.dumps(old, sort_keys=True, default=str) == json.dumps(new, sort_keys=True, default=str):
        return None   # as JSON: a tuple now is the list the manifest read back
    return f"{path or 'configuration'}: {_short(old)} then, {_short(new)} now"


def _short(value: Any) -> str:
    """A plugin block by its name (a block added or removed printed every parameter)."""
    if isinstance(value, Mapping) and "name" in value:
        return f"{{name: {value['name']!r}, ...}}"
    return repr(value)


def plugin_distribution(cls: type) -> dict[str, str]:
    """{distribution: version} of the installed package a third-party plugin class comes from
    (recorded in the run's configuration, so in its hash and manifest); empty for mata-eval's
    own plugins and for a class loaded by path from a folder that is not an installed package."""
    top = cls.__module__.split(".")[0]
    if top in ("mata_eval", "mata_eval_plugins"):
        return {}
    return {d: md.version(d) for d in _distributions().get(top, ())}


@functools.lru_cache(maxsize=1)
def _distributions() -> Mapping[str, list[str]]:
    return md.packages_distributions()


def _plugin_block(kind: str, value: Any, where, registry: Registry) -> PluginBlock | None:
    key = kind
    if value is None:
        if key in NULLABLE:
            return None
        raise ConfigError(where((key,)), (key,), f"expected a {kind} plugin block like {{name: ...}}, got null")
    if isinstance(value, str):
        value = {"name": value}
    if not isinstance(value, dict):
        raise ConfigError(where((key,)), (key,), f"expected a {kind} plugin block like {{name: ...}}, got {value!r}")
    name = value.get("name")
    if not isinstance(name, str):
        known = ", ".join(registry.names(kind)) or "(none installed)"
        raise ConfigError(where((key,)), (key,), f"missing `name` of the {kind} plugin; available: {known}")
    try:
        entry = registry.get(kind, name)
    except KeyError as exc:
        raise ConfigError(where((key, "name")), (key, "name"), str(exc.args[0])) from None
    params = build_params(entry.cls.Params, {k: v for k, v in value.items() if k != "name"}, (key,), where)
    return PluginBlock(kind, name, entry.cls, params)
