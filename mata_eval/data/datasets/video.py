"""A video file as one sequence (``dataset: {name: video, path: flight.mp4, init_box: [x, y, w,
h]}``): frames decoded with OpenCV (``cv2.VideoCapture``, the codecs of its FFmpeg build), the
tracker started from ``init_box`` on frame 0. Without a ground-truth file a run gives outputs and
timings only (every metric is NaN); with ``groundtruth`` (one ``x,y,w,h`` line per frame) it is
scored like any dataset."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ...core.hooks import hookimpl
from ...core.params import param
from ...core.sequence import FrameReadError, Sequence
from ...core.types import Box
from .annotations import DatasetError, check_fps, read_boxes, where


class VideoFrames:
    """``k -> image`` of a video file: reads on from the current position, seeks otherwise (one
    ``cv2.VideoCapture`` per process, opened on first use; thread-safe)."""

    def __init__(self, path: Path):
        self.path = path
        self._cap: cv2.VideoCapture | None = None
        self._next = 0
        self._lock = threading.Lock()

    def __call__(self, k: int) -> np.ndarray:
        with self._lock:
            if self._cap is None:
                self._cap = open_video(self.path)
            if k != self._next:
                self._cap.set(cv2.CAP_PROP_POS_FRAMES, k)
            ok, img = self._cap.read()
            if not ok or img is None:
                self._next = -1
                raise FrameReadError(f"cannot read frame {k} of video {self.path}")
            self._next = k + 1
            return img

    def __getstate__(self):  # picklable: the capture is reopened in the other process
        return {"path": self.path}

    def __setstate__(self, state):
        self.__init__(state["path"])


def open_video(path: Path) -> cv2.VideoCapture:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise DatasetError(f"video: cannot open {path} (not a video file OpenCV can decode)")
    return cap


class VideoDataset:
    """A video file (mp4, avi, mkv, ...) as one sequence: initial box given, ground truth optional."""

    name = "video"

    @dataclass(frozen=True)
    class Params:
        path: str = field(metadata={"doc": "video file (any container/codec OpenCV's FFmpeg reads)"})
        init_box: list[float] | None = param(None, "x, y, w, h of the target in frame 0 (default: the first ground-truth line)")
        groundtruth: str | None = param(None, "ground-truth file, one x,y,w,h line per frame (default: none, not scored)")
        fps: float | None = param(None, "frame rate (default: the file's)")
        frames: int | None = param(None, "use only the first N frames")
        sequence: str | None = param(None, "sequence name (default: the file name without extension)")

        def __post_init__(self) -> None:
            if self.init_box is None and self.groundtruth is None:
                raise ValueError("video: give init_box: [x, y, w, h] (the target in frame 0) or a groundtruth file")
            if self.init_box is not None and (len(self.init_box) != 4 or not Box.from_array(self.init_box).is_valid):
                raise ValueError(f"video: init_box: expected [x, y, w, h] with w, h > 0, got {self.init_box!r}")
            check_fps("video", self.fps)
            if self.frames is not None and self.frames < 1:
                raise ValueError(f"video: frames: expected a positive number of frames, got {self.frames!r}")

    def __init__(self, params: Params):
        self.params = params

    def sequences(self) -> list[Sequence]:
        p = self.params
        path = Path(p.path).expanduser()
        if not path.is_file():
            raise DatasetError(f"video: file not found: {where(path)}")
        cap = open_video(path)
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = p.fps or float(cap.get(cv2.CAP_PROP_FPS))
        cap.release()
        if n <= 0:
            raise DatasetError(f"video: {path}: the file gives no frame count")
        if not fps > 0:
            raise DatasetError(f"video: {path}: the file gives no frame rate; set fps")
        if p.frames is not None:
            n = min(n, p.frames)
        if p.groundtruth is not None:
            gt = read_boxes(p.groundtruth)
            # one line per frame; more lines only with `frames` (the first N of both): a longer
            # file is another sequence's (QA pass: cut to the video and scored)
            if len(gt) < n or (len(gt) > n and p.frames is None):
                raise DatasetError(f"{p.groundtruth}: {len(gt)} ground-truth lines but {n} frames in {path}; "
                                   "expected one line per frame (frames: N uses the first N of each)")
            gt = gt[:n]
        else:
            gt = np.full((n, 4), np.nan)
        init = Box.from_array(p.init_box) if p.init_box is not None else None
        if init is None and not Box.from_array(gt[0]).is_valid:
            raise DatasetError(f"{p.groundtruth}:1: no target in frame 0; give init_box")
        return [Sequence(name=p.sequence or path.stem, groundtruth=gt, fps=fps, loader=VideoFrames(path),
                         init=init, meta={"source": str(path)})]


@hookimpl
def mata_eval_datasets() -> list[type]:
    return [VideoDataset]
