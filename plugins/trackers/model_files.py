"""Finding pretrained model files: a path from the YAML block, else an environment variable.

Nothing is downloaded at run time; a missing file raises :class:`ModelFileNotFound` naming the
expected file, how to point to it, and where to get it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class ModelFile:
    """One expected model file: its usual name, the YAML key and env var that locate it, and
    where it is published."""

    file_name: str
    yaml_key: str
    env_var: str
    source: str


MODEL_FILES = {
    "vittrack": ModelFile(
        "object_tracking_vittrack_2023sep.onnx", "model", "MATA_VITTRACK_ONNX",
        "https://github.com/opencv/opencv_zoo/tree/main/models/object_tracking_vittrack"),
    "nanotrack_backbone": ModelFile(
        "nanotrack_backbone_sim.onnx", "backbone", "MATA_NANOTRACK_BACKBONE",
        "https://github.com/HonglinChu/SiamTrackers/tree/master/NanoTrack/models/nanotrackv2"),
    "nanotrack_head": ModelFile(
        "nanotrack_head_sim.onnx", "head", "MATA_NANOTRACK_HEAD",
        "https://github.com/HonglinChu/SiamTrackers/tree/master/NanoTrack/models/nanotrackv2"),
}

# Where the project's shared data keeps them (used only as a last resort, for tests/benchmarks)
_SHARED_LAYOUT = {
    "vittrack": "models/vittrack/object_tracking_vittrack_2023sep.onnx",
    "nanotrack_backbone": "models/nanotrack/v2/nanotrack_backbone_sim.onnx",
    "nanotrack_head": "models/nanotrack/v2/nanotrack_head_sim.onnx",
}


def exported_graphs(folder: str | Path, model: str) -> dict[str, Path]:
    """The graph files of a ``mata-eval export`` folder as its export.json lists them, keyed
    ``onnx_<role>`` (``onnx_full``, ``onnx_template``, ...): what a run's manifest records."""
    from mata_eval.deploy.export import read_manifest

    root = Path(folder).expanduser()
    return {f"onnx_{role}": root / g["file"] for role, g in read_manifest(root, model).get("graphs", {}).items()}


class ModelFileNotFound(FileNotFoundError):
    """A pretrained model file is missing; the message says which file and where to get it."""


def _shared_data() -> Path | None:
    env = os.environ.get("MATA_SHARED_DATA")
    if env:
        return Path(env)
    guess = Path(__file__).resolve().parents[2].parent / "shared" / "data"
    return guess if guess.is_dir() else None


def resolve_model(key: str, configured: str | None) -> Path:
    """The path of model file ``key``: ``configured`` (the YAML value) if given, else the
    environment variable, else the shared-data copy beside the repository (``$MATA_SHARED_DATA``
    or ``../shared/data``). Raises :class:`ModelFileNotFound` when the file is not there."""
    spec = MODEL_FILES[key]
    if configured:
        path, origin = Path(configured).expanduser(), f"YAML parameter '{spec.yaml_key}'"
    elif os.environ.get(spec.env_var):
        path, origin = Path(os.environ[spec.env_var]).expanduser(), f"${spec.env_var}"
    else:
        shared = _shared_data()
        path = shared / _SHARED_LAYOUT[key] if shared is not None else None
        origin = "no YAML parameter or environment variable"
        if path is None or not path.is_file():
            raise ModelFileNotFound(
                f"{spec.file_name} not found: set the tracker's YAML parameter '{spec.yaml_key}' or "
                f"${spec.env_var} to its path. Get it from {spec.source} (no download at run time).")
    if path.is_dir():
        path = path / spec.file_name
    if not path.is_file():
        raise ModelFileNotFound(
            f"{spec.file_name} not found at {path} (from {origin}). Get it from {spec.source} and set "
            f"the YAML parameter '{spec.yaml_key}' or ${spec.env_var} to its path (no download at run time).")
    return path
