"""A tracking sequence: ground truth, attributes, fps, and lazily loaded frames."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator, Mapping

import cv2
import numpy as np

from .types import Box, Frame


class FrameReadError(RuntimeError):
    """A frame could not be read (missing or corrupt file)."""


@dataclass(frozen=True, eq=False)
class Sequence:
    """One sequence of a dataset.

    ``groundtruth``: (N, 4) float ``x, y, w, h`` as the annotation file gives them; rows that are
    not annotated are NaN, rows where the target is absent are NaN or a zero-size box (DTB70's
    ``0,0,0,0``), and the metric profile decides what they count as (:mod:`mata_eval.score.metrics`).
    ``annotated``: optional (N,) bool mask for sparse ground truth (VTUAV: every 10th frame);
    ``None`` means every frame is annotated.
    ``frame_paths``: one image path per frame (may be empty when only annotations are loaded).
    ``loader``: optional ``k -> image`` that replaces reading ``frame_paths`` (synthetic data,
    on-the-fly occlusion augmentation).
    ``meta``: free-form per-sequence extras (e.g. per-frame occlusion fractions, true
    homographies) keyed by name.
    ``init``: the box the tracker starts from when it is not the ground truth of frame 0 (a
    flight video without ground truth: every ``groundtruth`` row NaN, nothing scored).
    """

    name: str
    groundtruth: np.ndarray
    fps: float = 30.0
    attributes: frozenset[str] = frozenset()
    frame_paths: tuple[str, ...] = ()
    loader: Callable[[int], np.ndarray] | None = field(default=None, repr=False)
    annotated: np.ndarray | None = None
    meta: Mapping[str, object] = field(default_factory=dict, repr=False)
    init: Box | None = None

    def __len__(self) -> int:
        return int(self.groundtruth.shape[0])

    @property
    def init_box(self) -> Box:
        """The box that initialises the tracker: ``init``, else the ground truth of frame 0."""
        return self.init if self.init is not None else Box.from_array(self.groundtruth[0])

    def image(self, k: int) -> np.ndarray:
        """Frame ``k`` as a BGR uint8 array; raises :class:`FrameReadError` naming the file."""
        if self.loader is not None:
            return self.loader(k)
        if not self.frame_paths:
            raise FrameReadError(f"sequence {self.name!r} was loaded without frames (annotations only)")
        path = self.frame_paths[k]
        img = cv2.imread(path, cv2.IMREAD_COLOR)
        if img is None:
            raise FrameReadError(f"cannot read frame {k} of sequence {self.name!r}: {path}")
        return img

    def frames(self) -> Iterator[Frame]:
        """Frames with their camera times ``t = k / fps``; images load on first access."""
        for k in range(len(self)):
            yield Frame(k=k, t=k / self.fps, loader=(lambda k=k: self.image(k)))
