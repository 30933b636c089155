"""VTUAV (Zhang et al., CVPR 2022), visible (RGB) part of the test split, sparse ground truth::

    <root>/test_ST/<seq>/rgb/000000.jpg ...       visible frames (ir/ holds the thermal ones)
    <root>/test_ST/<seq>/rgb.txt                  one x,y,w,h line per annotated frame

Only every 10th frame is annotated (frames 0, 10, 20, ...): the sequence has one ground-truth row
per frame, NaN where not annotated, and ``annotated`` marks the annotated frames; metrics score
those only (paper, section 4: predictions are sub-sampled for VTUAV). With the ``rgb/`` folder
present the frame count is its image count; without it (evaluating results from annotations
only) the sequence ends at the last annotated frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...core.hooks import hookimpl
from ...core.params import param
from ...core.sequence import Sequence
from .annotations import AnnotationError, DatasetError, MissingFrames, check_fps, list_images, read_boxes, select


def expand_sparse(rows: np.ndarray, n_frames: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame ground truth and annotated mask from rows annotating frames 0, step, 2*step, ..."""
    gt = np.full((n_frames, 4), np.nan)
    idx = np.arange(len(rows)) * step
    gt[idx] = rows
    mask = np.zeros(n_frames, dtype=bool)
    mask[idx] = True
    return gt, mask


class VTUAV:
    """VTUAV test split, visible part (<split>/<seq>/rgb/, rgb.txt), ground truth every 10th frame."""

    name = "vtuav"
    label = "VTUAV"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        root: str = field(metadata={"doc": "dataset folder holding the test split folder"})
        sequences: list[str] | None = param(None, "names of the sequences to load (default: all)")
        split: str = param("test_ST", "folder of the split under root (test_ST short-term, test_LT long-term)")
        annotation_step: int = param(10, "frames between two annotated frames (VTUAV: 10)")
        fps: float = param(30.0, "camera frame rate (frames per second)")

        def __post_init__(self) -> None:
            check_fps("vtuav", self.fps)

    def __init__(self, params: Params):
        if params.annotation_step < 1:
            raise DatasetError(f"annotation_step: expected an integer >= 1, got {params.annotation_step}")
        self.params = params
        self.root = Path(params.root).expanduser()

    @property
    def split_dir(self) -> Path:
        return self.root / self.params.split if self.params.split else self.root

    def sequences(self) -> list[Sequence]:
        base = self.split_dir
        if not base.is_dir():
            raise DatasetError(f"VTUAV split folder not found: {base}; expected <root>/{self.params.split}/<seq>/rgb.txt "
                               "(set split: to the test split's folder name)")
        files = {d.name: d / "rgb.txt" for d in sorted(base.iterdir()) if (d / "rgb.txt").is_file()}
        if not files:
            raise DatasetError(f"{base}: no <seq>/rgb.txt found (VTUAV visible ground truth)")
        names = select(sorted(files), self.params.sequences, f"dataset vtuav ({base})")
        return [self._load(name, files[name]) for name in names]

    def _load(self, name: str, gt_path: Path) -> Sequence:
        step = self.params.annotation_step
        rows = read_boxes(gt_path, allow_polygons=False)
        folder = gt_path.parent / "rgb"
        frames = list_images(folder)
        n = len(frames) if frames else (len(rows) - 1) * step + 1
        if len(rows) == n and step > 1 and frames:
            gt, mask = rows, None  # a dense file (one line per frame)
        else:
            if not (len(rows) - 1) * step < n <= len(rows) * step:
                raise AnnotationError(gt_path, None, f"{len(rows)} annotation lines do not fit {n} frames in {folder} "
                                                     f"with one annotation every {step} frames (expected "
                                                     f"{-(-n // step)} lines, or {n} for dense annotation)")
            gt, mask = expand_sparse(rows, n, step)
        return Sequence(name=name, groundtruth=gt, fps=self.params.fps, frame_paths=tuple(frames),
                        loader=None if frames else MissingFrames(name, [folder]), annotated=mask,
                        meta={"annotation_step": step})


@hookimpl
def mata_eval_datasets() -> list[type]:
    return [VTUAV]
