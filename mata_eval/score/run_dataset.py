"""The dataset a mata-eval run folder was made on, as ``mata-eval eval`` and
``mata_eval.evaluate`` load it again: the dataset parameters of the run's manifest with the
user's on top, relative paths read from the folder the run ran in, and the run's occlusion
augmentation (the AOC attribute and the occluded frames)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Mapping

from ..run import results

#: dataset parameters that are paths (relative ones are relative to the folder a command runs in)
PATH_PARAMS = ("root", "annotations")


def manifest_or_nothing(folder: str | Path) -> dict[str, Any]:
    """A folder's manifest.json, or an empty mapping (none, unreadable)."""
    try:
        return results.read_manifest(Path(folder)) or {}
    except (OSError, ValueError):
        return {}


def dataset_name(manifest: Mapping[str, Any]) -> str | None:
    """The dataset plugin a run folder's manifest names, or None."""
    config = manifest.get("config")
    ds = config.get("dataset") if isinstance(config, Mapping) else None
    return ds.get("name") if isinstance(ds, Mapping) and isinstance(ds.get("name"), str) else None


def run_manifest(folder: str | Path, dataset: str) -> dict[str, Any]:
    """A mata-eval run folder's manifest when its dataset is the plugin ``dataset`` (its
    ``config`` the run's resolved configuration); empty otherwise (another layout, another
    dataset, no manifest)."""
    manifest = manifest_or_nothing(folder)
    return manifest if dataset_name(manifest) == dataset else {}


def run_dataset_values(manifest: Mapping[str, Any], given: Mapping[str, Any]) -> dict[str, Any]:
    """The run's dataset parameters (``manifest``: :func:`run_manifest`) with those the user
    gave on top (``given``; ``None``: the default, :func:`defaults_for_none`): a ``--set``
    changed one of them and dropped the others (for the synthetic suite, a 1.1 GB default suite
    was rendered and then refused on its frame count). The user's relative paths are made
    absolute, as the run's are read from the folder it ran in (:func:`results.in_run_cwd`)."""
    own = {k: v for k, v in manifest["config"]["dataset"].items() if k != "name" and v is not None}
    mine = {k: str(Path(v).resolve()) if k in PATH_PARAMS and isinstance(v, str) else v for k, v in given.items()}
    return {**own, **mine}


def defaults_for_none(params_cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` without the parameters of ``params_cls`` given as None (``--set KEY=null``: its
    default); an unknown name stays, so that building the parameters names it (QA pass 16c:
    ``--set sequencez=null`` was accepted without a word)."""
    import dataclasses

    known = {f.name for f in dataclasses.fields(params_cls)}
    return {k: v for k, v in values.items() if v is not None or k not in known}


def as_the_run_saw_them(seqs: list, config: Mapping[str, Any], lost: Callable[[str], None]) -> list:
    """``seqs`` with the run's occlusion augmentation (``config``: its manifest's, with
    ``occlusion`` and ``seed``), which adds the AOC attribute and the occluded frames: scored
    without it, a run made with ``occlusion: {}`` lost its occlusion group. Reads each
    sequence's frame 0 (its size); without frames, ``seqs`` as they are, and ``lost`` is given
    a line saying what that loses."""
    if not config.get("occlusion"):
        return seqs
    from ..core.params import build_params
    from ..core.sequence import FrameReadError
    from ..data.occlusion import OcclusionParams, augment_sequence

    params, seed = build_params(OcclusionParams, config["occlusion"]), int(config.get("seed", 0))
    try:
        augmented = [augment_sequence(s, params, seed) for s in seqs]
    except FrameReadError as exc:   # annotations only: the occluders' placement needs the image size
        lost(f"scored without the run's occlusion augmentation (no AOC group, no occluded-frame scores): it "
             f"needs each sequence's frame 0 ({exc})")
        return seqs
    return augmented
