"""The built-in synthetic UAV suite (:mod:`mata_eval.data.synth`) as a dataset plugin.

The suite is generated on first use into a cache folder keyed by its generation parameters
(atomically: a crash never leaves a half suite that looks complete), then read through the
official-layout loader :class:`mata_eval.data.datasets.uav123.UAV123`, exactly as a real UAV123 copy
would be. Each sequence's true inter-frame homographies are in ``meta["homographies"]``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import multiprocessing
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Literal

import filelock

from ...core.hooks import hookimpl
from ...core.params import param
from ...core.sequence import Sequence
from .annotations import DatasetError


def cache_root() -> Path:
    """``$MATA_EVAL_CACHE`` or ``~/.cache/mata-eval``."""
    env = os.environ.get("MATA_EVAL_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "mata-eval"


#: the suite's generation parameters when neither the experiment nor a suite at ``root`` sets them
GENERATION_DEFAULTS = {"n_sequences": 20, "n_frames": 300, "width": 1280, "height": 720, "seed": 0,
                       "motion": "uav123"}


class SyntheticDataset:
    """Synthetic UAV sequences with exact ego-motion (generated on first use, then cached)."""

    name = "synthetic"
    label = "Synthetic"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        root: str | None = param(None, "suite folder (default: $MATA_EVAL_CACHE or ~/.cache/mata-eval, "
                                       "synthetic/<hash of the generation parameters>)")
        n_sequences: int | None = param(None, "number of sequences (default 20; a suite at root: its own)")
        n_frames: int | None = param(None, "frames per sequence, 30 fps (default 300; a suite at root: its own)")
        width: int | None = param(None, "frame width in pixels (default 1280; a suite at root: its own)")
        height: int | None = param(None, "frame height in pixels (default 720; a suite at root: its own)")
        seed: int | None = param(None, "generation seed: same seed, same pixels, names and attributes "
                                       "(default 0; a suite at root: its own)")
        motion: Literal["uav123", "legacy"] | None = param(
            None, "camera model: uav123 (image-plane motion matched to UAV123) or legacy (generator "
                  "version 3: the target nearly still in the image); default uav123, a suite at root: its own")
        sequences: list[str] | None = param(None, "names of the sequences to load (default: all)")
        jobs: int = param(2, "worker processes used to generate the suite")

        def __post_init__(self) -> None:
            # a generation parameter left out is the suite's at root (one written by `mata-eval
            # synth`, read without repeating its options), else the default; resolved here, so
            # that the manifest and the config hash hold the values
            from ..synth import read_suite_info

            suite = ((read_suite_info(Path(self.root).expanduser()) or {}).get("suite") or {}) if self.root else {}
            for key, default in GENERATION_DEFAULTS.items():
                if getattr(self, key) is None:
                    object.__setattr__(self, key, suite.get(key, default))

    def __init__(self, params: Params):
        self.params = params
        p = params
        for key in ("n_sequences", "n_frames", "width", "height", "jobs"):
            if getattr(p, key) < 1:
                raise DatasetError(f"dataset synthetic: {key} must be >= 1, got {getattr(p, key)}")

    @property
    def generation(self) -> dict:
        p = self.params
        return {"n_sequences": p.n_sequences, "n_frames": p.n_frames, "width": p.width, "height": p.height,
                "seed": p.seed, "motion": p.motion}

    @property
    def root(self) -> Path:
        if self.params.root:
            return Path(self.params.root).expanduser()
        import cv2

        from ..synth import GENERATOR_VERSION

        # The frames depend on OpenCV's warpPerspective too (5.1 moved 1 grey level on some pixels
        # of 4-17% of 5.0's frames, docs/results.md): a suite per OpenCV release, so that a run's
        # numbers follow from the installed software, not from when the cache was filled
        key = json.dumps({**self.generation, "version": GENERATOR_VERSION, "opencv": cv2.__version__}, sort_keys=True)
        return cache_root() / "synthetic" / hashlib.sha256(key.encode()).hexdigest()[:16]

    def check(self) -> None:
        """Preflight: a suite already at :attr:`root` matches the asked parameters and has the
        ``sequences`` asked for (a missing one is generated on first use)."""
        from ..synth import read_suite_info

        root = self.root
        if root.exists() and read_suite_info(root) is None and any(root.iterdir()):
            raise DatasetError(f"dataset synthetic: {root} exists and is not a synthetic suite; choose another root")
        self._check_suite(root, read_suite_info(root))
        self.sequence_names()

    def sequence_names(self) -> list[str]:
        """The names :meth:`sequences` will have, without generating the suite (the preflight
        checks ``--sequences`` and ``sequences:`` against them: a typo cost a whole suite's
        rendering first)."""
        from ..synth import read_suite_info
        from ..synth.spec import suite_name
        from .annotations import select

        info = read_suite_info(self.root)
        names = ([sp["name"] for sp in info.get("sequences", [])] if info
                 else [suite_name(i) for i in range(self.params.n_sequences)])
        return select(names, self.params.sequences, "dataset synthetic: sequences")

    def _check_suite(self, root: Path, info: dict | None) -> None:
        suite = (info or {}).get("suite")
        if suite is not None and suite != self.generation:
            diff = ", ".join(f"{k}={suite.get(k)!r} (asked {v!r})" for k, v in self.generation.items()
                             if suite.get(k) != v)
            raise DatasetError(f"dataset synthetic: {root} holds a suite generated with other parameters: {diff}; "
                               "use another root or the matching parameters")

    def ensure(self) -> Path:
        """Generate the suite at :attr:`root` unless a complete one is there; returns the root."""
        import sys

        from ..synth import read_suite_info, write_suite

        root = self.root
        info = read_suite_info(root)
        if info is None:
            try:
                with self._generating(root):   # one process renders it, the others wait for it
                    if read_suite_info(root) is None:
                        g = self.generation
                        print(f"generating the synthetic suite ({g['n_sequences']} sequences x {g['n_frames']} "
                              f"frames, {g['width']}x{g['height']}) into {root} (first use only)",
                              file=sys.stderr, flush=True)
                        write_suite(root, **g, jobs=self.params.jobs, progress=True)
            except FileExistsError:
                if read_suite_info(root) is None:   # (else another process finished first: its suite)
                    raise DatasetError(f"dataset synthetic: {root} exists and is not a synthetic suite; "
                                       "choose another root") from None
            except OSError as exc:   # a read-only or full cache
                raise DatasetError(f"dataset synthetic: cannot write the suite into {root.parent} ({exc.strerror or exc}): "
                                   "set MATA_EVAL_CACHE to a writable folder, or root: to a folder holding a "
                                   "generated suite") from None
            info = read_suite_info(root)
        self._check_suite(root, info)
        return root

    @staticmethod
    @contextlib.contextmanager
    def _generating(root: Path) -> Iterator[None]:
        """Held while generating the suite at ``root``: the processes of a run (the task workers of
        every node sharing the cache, several drivers) would each render all of it at once. The
        wait ends when the suite appears, whoever holds the lock; on a file system without locks
        (``flock`` refused) each process generates as before, the atomic write settling the race."""
        import sys

        from ..synth import read_suite_info

        root.parent.mkdir(parents=True, exist_ok=True)
        if multiprocessing.parent_process() is not None:
            # a child of a process that may hold the lock and wait for it (a script without the
            # `if __name__ == "__main__":` guard, re-imported by a generator worker): no lock, so
            # it fails as before instead of waiting for ever
            yield
            return
        lock = filelock.FileLock(str(root.parent / f".{root.name}.lock"))
        said = False
        while True:
            try:
                lock.acquire(timeout=0 if not said else 5)
                locked = True
                break
            except filelock.Timeout:   # (a TimeoutError, so before OSError)
                if read_suite_info(root) is not None:
                    locked = False
                    break
                if not said:
                    print(f"waiting for another process generating the synthetic suite into {root}",
                          file=sys.stderr, flush=True)
                    said = True
            except (OSError, NotImplementedError):
                locked = False
                break
        try:
            yield
        finally:
            if locked:
                lock.release()

    def sequences(self) -> list[Sequence]:
        return read_suite(self.ensure(), self.params.sequences)


def read_suite(root: str | Path, sequences: list[str] | None = None) -> list[Sequence]:
    """The sequences of a generated suite (as written by ``mata-eval synth``), read through the
    UAV123 loader, with the true homographies in ``meta["homographies"]``."""
    import dataclasses

    from ..synth import load_true_homographies, read_suite_info
    from .uav123 import UAV123

    root = Path(root)
    info = read_suite_info(root) or {}
    sizes = {sp["name"]: (sp["width"], sp["height"]) for sp in info.get("sequences", [])}
    reader = UAV123(UAV123.Params(root=str(root), sequences=sequences))
    out = []
    for seq in reader.sequences():
        meta = {**seq.meta, "homographies": load_true_homographies(root, seq.name), "synthetic": True}
        if seq.name in sizes:
            meta["image_size"] = sizes[seq.name]
        out.append(dataclasses.replace(seq, meta=meta))
    return out


@hookimpl
def mata_eval_datasets() -> list[type]:
    return [SyntheticDataset]
