"""What a plugin of each kind must provide (small ``typing.Protocol`` interfaces).

Every plugin is a class with:
- ``name``: the name used in YAML and in ``mata-eval list``;
- a docstring whose first line is the one-line description shown by ``mata-eval list``;
- ``Params``: a frozen dataclass declaring its parameters (see :mod:`mata_eval.params`);
- ``__init__(self, params: Params)``.

Heavy optional dependencies (torch, onnxruntime, TensorRT) are imported inside methods, never at
module import, so that ``mata-eval list`` works without them.
"""

from __future__ import annotations

from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from . import sequence
from .types import Box, Estimate, Motion, Stamped, TrackerOutput


@runtime_checkable
class Tracker(Protocol):
    """Block A. ``prior`` is the search-region centre ``(cx, cy)`` in image pixels proposed by
    the estimator (paper, end of section 2.3); ``None`` means "use your own last box".

    A tracker holding a resource (a process, a device) may also define ``close()``: the runner
    calls it once the sequence is over, finished or failed."""

    def initialize(self, image: np.ndarray, box: Box) -> None: ...

    def track(self, image: np.ndarray, prior: tuple[float, float] | None = None) -> TrackerOutput: ...


@runtime_checkable
class EgoMotion(Protocol):
    """Block B. ``estimate`` returns the motion from the image previously given (to
    ``initialize`` or ``estimate``) to this one. Degenerate input gives ``Motion.invalid()``,
    never an exception."""

    def initialize(self, image: np.ndarray) -> None: ...

    def estimate(self, image: np.ndarray) -> Motion: ...


@runtime_checkable
class Estimator(Protocol):
    """Block C. ``step`` is called at each estimator tick (camera time ``t``) with the block
    outputs published since the previous call, oldest first; each carries its capture time.
    A tick may make two calls at the same ``t``: first with the camera motion (the estimate the
    tracker then uses as its search centre), then with a detection published at ``t`` itself."""

    def initialize(self, box: Box, t: float) -> Estimate: ...

    def step(
        self,
        t: float,
        motions: Sequence[Stamped[Motion]] = (),
        detections: Sequence[Stamped[TrackerOutput]] = (),
    ) -> Estimate: ...


@runtime_checkable
class Dataset(Protocol):
    """A collection of sequences. Loading the list reads annotations only; frames load lazily."""

    def sequences(self) -> list[sequence.Sequence]: ...
