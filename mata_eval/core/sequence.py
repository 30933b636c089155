"""A tracking sequence: ground truth, attributes, fps, and lazily loaded frames."""

from __future__ import annotations

import collections.abc
from dataclasses import dataclass, field
from typing import Callable, Iterator, Mapping

import cv2
import numpy as np

from .types import Box, Frame


class FrameReadError(RuntimeError):
    """A frame could not be read (missing, truncated or corrupt file)."""


JPEG_START, JPEG_END = b"\xff\xd8", b"\xff\xd9"


def read_image(path: str) -> np.ndarray:
    """The image file ``path`` as a BGR uint8 array, decoded by OpenCV (as ``cv2.imread``).

    Raises :class:`FrameReadError` for a file that is missing, does not decode, or is a JPEG
    without its end marker: OpenCV decodes a truncated JPEG into a grey-filled image and only
    prints "Premature end of JPEG file", which would score a corrupted frame silently."""
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise FrameReadError(f"cannot read {path}: {exc.strerror or exc}") from None
    head = data[:2].tobytes()
    if head == JPEG_START and JPEG_END not in data[-64:].tobytes():  # padding may follow the marker
        raise FrameReadError(f"{path}: truncated JPEG (no end-of-image marker)")
    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if img is None:
        raise FrameReadError(f"{path}: cannot decode the image")
    return img


class FramePaths(collections.abc.Sequence):
    """A sequence's ``n`` frame paths, listed or named by ``make()`` on first access: scoring
    reads only the annotations, and listing or naming every frame of a dataset (15,777 for
    DTB70) was most of the time of ``mata-eval eval``. ``make`` may raise (e.g. a folder whose
    image count differs from ``n``); it must return ``n`` paths."""

    def __init__(self, make: Callable[[], collections.abc.Sequence[str]], n: int):
        self._make, self._n = make, int(n)
        self._paths: tuple[str, ...] | None = None

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, k):  # type: ignore[override]
        if self._paths is None:
            paths = tuple(self._make())
            if len(paths) != self._n:
                raise FrameReadError(f"expected {self._n} frame paths, got {len(paths)}")
            self._paths = paths
        return self._paths[k]

    def __repr__(self) -> str:
        return f"FramePaths({self._n} frames)"

    def __reduce__(self):
        return tuple, (tuple(self),)  # to a worker process: the built paths (``make`` may be a lambda)


@dataclass(frozen=True, eq=False)
class Sequence:
    """One sequence of a dataset.

    ``groundtruth``: (N, 4) float ``x, y, w, h`` as the annotation file gives them; rows that are
    not annotated are NaN, rows where the target is absent are NaN or a zero-size box (DTB70's
    ``0,0,0,0``), and the metric profile decides what they count as (:mod:`mata_eval.score.metrics`).
    ``annotated``: optional (N,) bool mask for sparse ground truth (VTUAV: every 10th frame);
    ``None`` means every frame is annotated.
    ``frame_paths``: one image path per frame (may be empty when only annotations are loaded;
    a :class:`FramePaths` builds them on first access).
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
    frame_paths: collections.abc.Sequence[str] = ()
    loader: Callable[[int], np.ndarray] | None = field(default=None, repr=False)
    annotated: np.ndarray | None = None
    meta: Mapping[str, object] = field(default_factory=dict, repr=False)
    init: Box | None = None

    def __len__(self) -> int:
        return int(self.groundtruth.shape[0])

    def __repr__(self) -> str:   # not every path and ground-truth row (thousands of lines)
        where = "loader" if self.loader is not None else f"{len(self.frame_paths)} frame paths"
        return (f"Sequence({self.name!r}, {len(self)} frames at {self.fps:g} fps, "
                f"attributes={sorted(self.attributes)}, {where})")

    @property
    def init_box(self) -> Box:
        """The box that initialises the tracker: ``init``, else the ground truth of frame 0."""
        return self.init if self.init is not None else Box.from_array(self.groundtruth[0])

    def image(self, k: int) -> np.ndarray:
        """Frame ``k`` as a BGR uint8 array; raises :class:`FrameReadError` naming the file, or
        the frame when a ``loader`` gives something else (None, grey, BGRA, float)."""
        if self.loader is not None:
            img = self.loader(k)
            if not (isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.ndim == 3
                    and img.shape[2] == 3 and img.size):
                got = (f"{img.dtype} array of shape {img.shape}" if isinstance(img, np.ndarray)
                       else type(img).__name__)
                raise FrameReadError(f"frame {k} of sequence {self.name!r}: its loader gave a {got}; "
                                     "expected an (H, W, 3) uint8 BGR image")
            return img
        if not self.frame_paths:
            raise FrameReadError(f"sequence {self.name!r} was loaded without frames (annotations only)")
        try:
            return read_image(self.frame_paths[k])
        except FrameReadError as exc:
            raise FrameReadError(f"frame {k} of sequence {self.name!r}: {exc}") from None

    def frames(self) -> Iterator[Frame]:
        """Frames with their camera times ``t = k / fps``; images load on first access."""
        for k in range(len(self)):
            yield Frame(k=k, t=k / self.fps, loader=(lambda k=k: self.image(k)))
