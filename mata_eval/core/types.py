"""Core value types (DESIGN.md, "Core types"). Plain frozen dataclasses, no behaviour beyond
conversions.

Conventions used everywhere in mata-eval:
- boxes are ``x, y, w, h`` in float pixels with a top-left origin (UAV123 / pysot-toolkit files);
- images are ``numpy.uint8`` arrays of shape (H, W, 3) in **BGR** order, as ``cv2.imread`` returns;
- times are seconds on the camera clock, ``t = k / fps`` for frame ``k``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Callable, Generic, Hashable, Mapping, TypeVar

import numpy as np

T = TypeVar("T")


@dataclass(frozen=True)
class Box:
    """Axis-aligned box ``x, y, w, h`` (pixels, top-left origin)."""

    x: float
    y: float
    w: float
    h: float

    @property
    def cx(self) -> float:
        return self.x + self.w / 2.0

    @property
    def cy(self) -> float:
        return self.y + self.h / 2.0

    @property
    def center(self) -> tuple[float, float]:
        return (self.cx, self.cy)

    def corners(self) -> tuple[float, float, float, float]:
        """``(x_tl, y_tl, x_br, y_br)``, the EKF's measurement layout (paper eq. ekf_x_z)."""
        return (self.x, self.y, self.x + self.w, self.y + self.h)

    @classmethod
    def from_corners(cls, x1: float, y1: float, x2: float, y2: float) -> "Box":
        return cls(float(x1), float(y1), float(x2 - x1), float(y2 - y1))

    @classmethod
    def from_center(cls, cx: float, cy: float, w: float, h: float) -> "Box":
        return cls(float(cx - w / 2.0), float(cy - h / 2.0), float(w), float(h))

    @classmethod
    def from_array(cls, a: Any) -> "Box":
        x, y, w, h = (float(v) for v in np.asarray(a, dtype=float).reshape(4))
        return cls(x, y, w, h)

    def as_array(self) -> np.ndarray:
        return np.array([self.x, self.y, self.w, self.h], dtype=float)

    @property
    def is_valid(self) -> bool:
        """Finite with positive width and height."""
        return bool(0 < self.w < math.inf and 0 < self.h < math.inf
                    and math.isfinite(self.x) and math.isfinite(self.y))


class FrameImage(np.ndarray):
    """A camera frame's BGR image as the scheduler hands it to the blocks: a plain ``ndarray``
    to any plugin, plus a per-frame cache of what blocks derive from it (grey image, shrunk
    image...), so that each product is computed once per frame however many blocks ask for it.

    Use :func:`derived`, which also works on a plain array. Slices and arithmetic results of a
    ``FrameImage`` are not the frame any more and carry no cache. A subclass rather than a
    wrapper so that the block interfaces (``track(image)``, ``estimate(image)``) and third-party
    plugins see an ordinary image."""

    _derived: dict | None

    def __new__(cls, image: np.ndarray) -> "FrameImage":
        if isinstance(image, FrameImage) and image._derived is not None:
            return image  # already a frame: keep its cache (the runs of a task share one frame)
        obj = np.asarray(image).view(cls)
        obj._derived = {}
        return obj

    def __array_finalize__(self, obj: object) -> None:
        self._derived = None  # a view or a result of an operation: not the frame itself


def derived(image: np.ndarray, key: Hashable, make: Callable[[np.ndarray], T]) -> T:
    """``make(image)``, computed once per frame and shared when ``image`` is a
    :class:`FrameImage` (``key`` names the product and every parameter it depends on), computed
    on each call otherwise. Arrays are returned read-only: they are shared between blocks."""
    cache = getattr(image, "_derived", None)
    if cache is None:
        return make(image)
    if key not in cache:
        value = make(image.view(np.ndarray))
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
        cache[key] = value
    return cache[key]


@dataclass(frozen=True)
class Frame:
    """Camera frame ``k`` at time ``t = k / fps``. The image is read on first access, then
    kept (one decode per frame) as a :class:`FrameImage` shared by the blocks."""

    k: int
    t: float
    loader: Callable[[], np.ndarray] = field(repr=False, compare=False)

    @cached_property
    def image(self) -> FrameImage:
        return FrameImage(self.loader())


@dataclass(frozen=True, eq=False)
class TrackerOutput:
    """Block A's output: a box, a confidence in [0, 1], and optional distributions.

    ``pmfs``: (4, N) per-coordinate PMFs (left, top, right, bottom), MixFormerV2-style.
    ``score_map``: 2-D score map (e.g. 16x16 for VitTrack / OSTrack).
    ``extra``: other named scalars worth recording (raw peak score, MLP score, ...).
    """

    box: Box
    confidence: float
    pmfs: np.ndarray | None = None
    score_map: np.ndarray | None = None
    extra: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Motion:
    """Block B's output: homography ``H`` mapping points of the previous processed frame into
    the current one (h33 = 1), its 9x9 covariance (row-major vec(H), h33 = 1 chart) or None,
    the inlier count, the estimated point noise (px) and a validity flag. ``unchanged``: the
    current image is the previous one within compression noise (a repeated frame, e.g. a
    clip padded to a higher frame rate), so nothing in the image moved over this interval.
    No motion this time (too few points, a failed fit) is ``valid=False`` (:meth:`invalid`); a
    run fails the sequence, naming the plugin, on an H that is not 3x3, a covariance that is not
    9x9, or a valid motion whose H or covariance is not finite or whose h33 is 0."""

    H: np.ndarray
    cov: np.ndarray | None = None
    inliers: int = 0
    sigma: float | None = None
    valid: bool = True
    unchanged: bool = False

    @classmethod
    def identity(cls, valid: bool = True) -> "Motion":
        return cls(H=np.eye(3), cov=None, inliers=0, sigma=None, valid=valid)

    @classmethod
    def invalid(cls) -> "Motion":
        return cls.identity(valid=False)


@dataclass(frozen=True, eq=False)
class Estimate:
    """Block C's output: a box, where the estimator has one its state covariance, and what is
    fed back to the tracker as its search centre (paper L424; with ``feedback: true``): the box
    centre, or ``search`` where the estimator hands out another centre, or nothing when it
    withholds it (``feedback=False``: the tracker then searches where it would alone). A box of
    width or height 0 is "target lost"; a run refuses a box that is not finite, a search centre
    that is not two finite numbers and a covariance that is not a square matrix (or holds NaN)."""

    box: Box
    cov: np.ndarray | None = None
    feedback: bool = True
    search: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if isinstance(self.search, (np.ndarray, list)):   # e.g. a numpy array (cx, cy)
            try:
                object.__setattr__(self, "search", tuple(float(v) for v in self.search))
            except (TypeError, ValueError):
                pass   # not numbers: the run refuses it, naming the estimator

    @property
    def prior(self) -> tuple[float, float] | None:
        """The search centre handed to the tracker: ``search`` or the box centre, None when withheld."""
        if not self.feedback:
            return None
        return self.box.center if self.search is None else self.search

    def within(self, width: float, height: float, margin: float = 0.5) -> "Estimate":
        """This estimate kept within ``margin`` boxes of a ``width`` x ``height`` image (issue 14:
        a coasting estimate must not run away): the box centre, and the search centre if one is
        named, clamped to the image grown by ``margin`` times the box size on each side (the
        default leaves at least a corner of the box on the image). The estimate itself, unchanged,
        when both centres already lie there. The size and the covariance are kept."""
        b = self.box
        centre = within_image(b.center, b.w, b.h, width, height, margin)
        search = None if self.search is None else within_image(self.search, b.w, b.h, width, height, margin)
        if centre == b.center and search == self.search:
            return self
        x = b.x if centre[0] == b.cx else centre[0] - b.w / 2.0  # an axis inside keeps its bits
        y = b.y if centre[1] == b.cy else centre[1] - b.h / 2.0
        return replace(self, box=Box(x, y, b.w, b.h), search=search)


def within_image(centre: tuple[float, float], w: float, h: float, width: float, height: float,
                 margin: float = 0.5) -> tuple[float, float]:
    """A ``w`` x ``h`` box's centre clamped to the ``width`` x ``height`` image grown by ``margin``
    times the box size on each side (0.5: the box keeps at least a corner on the image). The one
    bound on estimates (:meth:`Estimate.within`) and on the priors trackers use (``usable_prior``)."""
    mx, my = margin * max(w, 0.0), margin * max(h, 0.0)
    return min(max(centre[0], -mx), width + mx), min(max(centre[1], -my), height + my)


@dataclass(frozen=True, eq=False)
class Stamped(Generic[T]):
    """A block output as it sits on the scheduler's board: the value, the camera time of the
    frame it was computed from (``t_capture``) and the time it became visible (``t_publish``)."""

    value: T
    t_capture: float
    t_publish: float
