"""The package layout of docs/architecture.md: imports go one way between the packages, no
module imports itself back through a cycle, the core knows no plugin, and the distribution
carries every package."""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10 (a Jetson's): the same parser, from the test extra
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "mata_eval"

#: package -> the packages it may import (besides itself). cli sits on top of everything.
ALLOWED = {
    "core": set(),
    "data": {"core"},
    "run": {"core", "data"},
    "score": {"core", "data", "run"},
    "report": {"core", "data", "run", "score"},
    "deploy": {"core", "data", "run"},
}
#: plugin names the core may spell: the experiment file's documented default protocol (LTP)
ALLOWED_NAMES = {("mata_eval.run.config", "ltp")}
#: the public plugin API faces: re-exports of core, importable by anyone
FACES = {"types", "params", "hooks"}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """Every mata_eval module a file imports, at the top or inside functions."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith(("mata_eval.", "mata_eval_plugins"))}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.startswith("mata_eval_plugins"):
                out.add(target)
                continue
            if not (target == "mata_eval" or target.startswith("mata_eval.")):
                continue
            for a in node.names:  # `from . import x` may import a module
                sub = f"{target}.{a.name}"
                out.add(sub if _exists(sub) else target)
    return out


def _exists(module: str) -> bool:
    p = ROOT.joinpath(*module.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


MODULES = {_module_name(p): p for p in PKG.rglob("*.py")}


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _layer(m) in ALLOWED))
def test_imports_go_one_way(module):
    layer = _layer(module)
    for target in _imports(MODULES[module]):
        if target.startswith("mata_eval_plugins"):
            # deploy/export.py exports three PyTorch tracker plugins to ONNX: the one exception
            assert module == "mata_eval.deploy.export", f"{module} imports the plugin module {target}"
            continue
        other = _layer(target)
        if other in (None, layer):
            continue
        assert other in ALLOWED[layer], f"{module} imports {target}: {layer}/ must not import {other}/"


def test_no_import_cycle():
    graph = {m: {t for t in _imports(p) if t in MODULES and t != m} for m, p in MODULES.items()}
    # a package's __init__ re-exporting its own modules is not a cycle of concepts
    for m in graph:
        graph[m] = {t for t in graph[m] if not (MODULES[t].name == "__init__.py" and m.startswith(t + "."))}
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(t):] + [t]))
            if t not in state:
                visit(t, path + [t])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])


def test_faces_only_re_export_core():
    for face in FACES:
        targets = _imports(PKG / f"{face}.py")
        assert targets == {f"mata_eval.core.{face}"}, (face, targets)


def test_core_and_reports_name_no_plugin():
    """No module of core, data, run, score or report (dataset plugins aside) names a tracker,
    ego-motion, estimator or protocol plugin: labels and meanings come from the plugin classes.
    (deploy/export.py and the CLI's export command are the per-model ONNX exporter.)"""
    names = [p.stem for p in (ROOT / "plugins").glob("*/*.py") if p.stem != "__init__"]
    plugin_names = {n for n in names if re.fullmatch(r"[a-z_0-9]+", n)} & {
        "kcf", "vittrack", "nanotrack", "mixformerv2", "ostrack", "grid_lk", "features", "identity",
        "homography_ekf", "zoh", "ltp", "dsp", "vot_rt", "eop"}
    assert plugin_names, "plugins/ not found"
    for module, path in MODULES.items():
        if module.startswith("mata_eval.data.datasets") or _layer(module) not in ("core", "data", "run", "score", "report"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in plugin_names
                    and (module, node.value) not in ALLOWED_NAMES):
                raise AssertionError(f"{module} names the plugin {node.value!r} in code")


def test_distribution_lists_every_package():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    present = {_module_name(p.parent / "__init__.py") for p in PKG.rglob("__init__.py")}
    assert present <= listed, f"pyproject.toml [tool.setuptools] packages misses {sorted(present - listed)}"
