"""A recorded ROS bag as one sequence (``dataset: {name: rosbag, path: flight.bag, image_topic:
/camera/image_raw, gt_topic: /target/roi}``): ROS 1 bags, ROS 2 bags (sqlite3 or MCAP storage, the
bag folder) and bare ``.mcap`` files, read with the ``rosbags`` library (``pip install
mata-eval[rosbag]``; no ROS installation needed).

- Images: ``sensor_msgs/Image`` (``bgr8``, ``rgb8``, ``bgra8``, ``rgba8``, ``mono8``, ``mono16``,
  ``bayer_*8``) or ``sensor_msgs/CompressedImage`` (JPEG, PNG), one frame per message in bag
  order. Frame rate: ``fps``, else 1 / the median interval of the image stamps.
- Ground truth (optional): ``sensor_msgs/RegionOfInterest``, ``geometry_msgs/PolygonStamped``
  (its bounding box), ``vision_msgs/BoundingBox2D``, ``Detection2D`` or ``Detection2DArray``
  (the first detection; an empty array = no target). A message is matched to the image with the
  same stamp (header stamps when the message has a header, else the bag's receive times), or the
  nearest within half a frame interval; frames without one are not scored. Without ``gt_topic``
  the run gives outputs and timings only, and ``init_box`` is required.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ...core.hooks import hookimpl
from ...core.params import param
from ...core.sequence import FrameReadError, Sequence
from ...core.types import Box
from .annotations import DatasetError, check_fps, where

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
_BAYER = {"bayer_rggb8": cv2.COLOR_BayerBG2BGR, "bayer_bggr8": cv2.COLOR_BayerRG2BGR,
          "bayer_gbrg8": cv2.COLOR_BayerGR2BGR, "bayer_grbg8": cv2.COLOR_BayerGB2BGR}


def _rosbags():
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise DatasetError("rosbag: reading bags needs the rosbags library: pip install 'mata-eval[rosbag]'") from None
    return AnyReader


def _open(path: Path):
    AnyReader = _rosbags()
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as exc:  # rosbags raises its own error types per format
        raise DatasetError(f"rosbag: cannot read {path}: {exc}") from None
    return reader


def _connections(reader, topic: str, path: Path, key: str):
    cons = [c for c in reader.connections if c.topic == topic]
    if not cons:
        topics = ", ".join(sorted(f"{c.topic} ({c.msgtype})" for c in reader.connections)) or "(none)"
        raise DatasetError(f"rosbag: {key}: no topic {topic!r} in {path}; its topics: {topics}")
    return cons


def _stamp_ns(msg: Any, receive_ns: int) -> tuple[int, bool]:
    """(time, from a header): the header stamp when the message has one, else the receive time."""
    header = getattr(msg, "header", None)
    if header is None:
        return int(receive_ns), False
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec), True


def decode_image(msg: Any, msgtype: str) -> np.ndarray:
    """A ``sensor_msgs`` Image / CompressedImage message as a BGR uint8 array."""
    if msgtype.endswith("CompressedImage"):
        img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"cannot decode a compressed image (format {msg.format!r})")
        return img
    enc, h, w, step = msg.encoding.lower(), int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if enc in ("mono16", "16uc1"):
        rows = data.reshape(h, step)[:, : 2 * w].copy().view(">u2" if msg.is_bigendian else "<u2")
        return cv2.cvtColor((rows >> 8).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    channels = {"bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4, "mono8": 1, "8uc1": 1, "8uc3": 3, **{b: 1 for b in _BAYER}}
    if enc not in channels:
        raise ValueError(f"unsupported image encoding {msg.encoding!r} (supported: {', '.join(sorted(channels))}, mono16)")
    c = channels[enc]
    img = data.reshape(h, step)[:, : w * c].reshape(h, w, c) if c > 1 else data.reshape(h, step)[:, :w]
    if enc in ("bgr8", "8uc3"):
        return np.ascontiguousarray(img)
    if enc in _BAYER:
        return cv2.cvtColor(np.ascontiguousarray(img), _BAYER[enc])
    code = {"rgb8": cv2.COLOR_RGB2BGR, "bgra8": cv2.COLOR_BGRA2BGR, "rgba8": cv2.COLOR_RGBA2BGR}.get(enc, cv2.COLOR_GRAY2BGR)
    return cv2.cvtColor(np.ascontiguousarray(img), code)


def box_of(msg: Any) -> np.ndarray:
    """``x, y, w, h`` of a ground-truth message (NaN: no target), by the fields it has."""
    if hasattr(msg, "x_offset"):  # sensor_msgs/RegionOfInterest
        return np.array([msg.x_offset, msg.y_offset, msg.width, msg.height], float)
    if hasattr(msg, "polygon"):  # geometry_msgs/PolygonStamped
        pts = np.array([[p.x, p.y] for p in msg.polygon.points], float).reshape(-1, 2)
        if len(pts) == 0:
            return np.full(4, np.nan)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        return np.array([lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]])
    if hasattr(msg, "detections"):  # vision_msgs/Detection2DArray: the first detection
        return box_of(msg.detections[0]) if len(msg.detections) else np.full(4, np.nan)
    if hasattr(msg, "bbox"):  # vision_msgs/Detection2D
        return box_of(msg.bbox)
    if hasattr(msg, "size_x"):  # vision_msgs/BoundingBox2D (centre: Pose2D, or .position in vision_msgs 4)
        c = getattr(msg.center, "position", msg.center)
        return np.array([c.x - msg.size_x / 2, c.y - msg.size_y / 2, msg.size_x, msg.size_y], float)
    raise ValueError("unsupported ground-truth message: expected sensor_msgs/RegionOfInterest, "
                     "geometry_msgs/PolygonStamped or vision_msgs BoundingBox2D / Detection2D(Array)")


class BagFrames:
    """``k -> image`` of an image topic: the k-th message fetched by its receive time (one reader
    per process, opened on first use; thread-safe)."""

    def __init__(self, path: Path, topic: str, receive_ns: list[int]):
        self.path, self.topic, self.receive_ns = path, topic, receive_ns
        self._reader = None
        self._lock = threading.Lock()

    def __call__(self, k: int) -> np.ndarray:
        with self._lock:
            if self._reader is None:
                self._reader = _open(self.path)
                self._cons = _connections(self._reader, self.topic, self.path, "image_topic")
            t = self.receive_ns[k]
            before = self.receive_ns.index(t)  # messages of the same receive time come in bag order
            msgs = list(self._reader.messages(connections=self._cons, start=t, stop=t + 1))
            if len(msgs) <= k - before:
                raise FrameReadError(f"cannot read frame {k} of {self.path} ({self.topic} at {t} ns)")
            con, _, raw = msgs[k - before]
            try:
                return decode_image(self._reader.deserialize(raw, con.msgtype), con.msgtype)
            except ValueError as exc:
                raise FrameReadError(f"frame {k} of {self.path} ({self.topic}): {exc}") from None

    def __getstate__(self):
        return {"path": self.path, "topic": self.topic, "receive_ns": self.receive_ns}

    def __setstate__(self, state):
        self.__init__(**state)


class RosbagDataset:
    """ROS 1 / ROS 2 bag or MCAP file (rosbags library): images of a topic, ground truth of another."""

    name = "rosbag"

    @dataclass(frozen=True)
    class Params:
        path: str = field(metadata={"doc": "ROS 1 .bag file, ROS 2 bag folder (sqlite3 or MCAP) or .mcap file"})
        image_topic: str = field(metadata={"doc": "topic of sensor_msgs/Image or CompressedImage messages"})
        gt_topic: str | None = param(None, "topic of the target's box (RegionOfInterest, PolygonStamped, "
                                           "vision_msgs Detection2D...); default: none, not scored")
        init_box: list[float] | None = param(None, "x, y, w, h of the target in frame 0 (default: its ground truth)")
        fps: float | None = param(None, "frame rate (default: from the image stamps)")
        sequence: str | None = param(None, "sequence name (default: the bag's file name without extension)")

        def __post_init__(self) -> None:
            if self.init_box is None and self.gt_topic is None:
                raise ValueError("rosbag: give init_box: [x, y, w, h] (the target in frame 0) or a gt_topic")
            if self.init_box is not None and (len(self.init_box) != 4 or not Box.from_array(self.init_box).is_valid):
                raise ValueError(f"rosbag: init_box: expected [x, y, w, h] with w, h > 0, got {self.init_box!r}")
            check_fps("rosbag", self.fps)

    def __init__(self, params: Params):
        self.params = params

    def sequences(self) -> list[Sequence]:
        p = self.params
        path = Path(p.path).expanduser()
        if not path.exists():
            raise DatasetError(f"rosbag: not found: {where(path)}")
        reader = _open(path)
        try:
            cons = _connections(reader, p.image_topic, path, "image_topic")
            bad = [c.msgtype for c in cons if c.msgtype not in IMAGE_TYPES]
            if bad:
                raise DatasetError(f"rosbag: image_topic {p.image_topic!r} carries {bad[0]}; expected "
                                   f"{' or '.join(IMAGE_TYPES)}")
            receive, stamps = [], []
            for con, t, raw in reader.messages(connections=cons):
                # the header alone would do, but rosbags deserialises whole messages
                receive.append(int(t))
                stamps.append(_stamp_ns(reader.deserialize(raw, con.msgtype), t)[0])
            gt_msgs = []
            if p.gt_topic is not None:
                for con, t, raw in reader.messages(connections=_connections(reader, p.gt_topic, path, "gt_topic")):
                    msg = reader.deserialize(raw, con.msgtype)
                    try:
                        gt_msgs.append((_stamp_ns(msg, t), box_of(msg)))
                    except ValueError as exc:
                        raise DatasetError(f"rosbag: gt_topic {p.gt_topic!r} ({con.msgtype}): {exc}") from None
        finally:
            reader.close()
        n = len(receive)
        if n == 0:
            raise DatasetError(f"rosbag: no message on {p.image_topic!r} in {path}")
        period_ns = 1e9 / p.fps if p.fps else 0.0
        for times in (stamps, receive):  # header stamps (capture times), else the bag's receive times
            if period_ns <= 0 and n > 1:
                period_ns = float(np.median(np.diff(np.asarray(times, dtype=np.int64))))
        if period_ns <= 0:
            raise DatasetError(f"rosbag: {path}: cannot tell the frame rate from the image stamps; set fps")
        fps = 1e9 / period_ns
        gt = match_ground_truth(np.asarray(stamps), np.asarray(receive), gt_msgs, period_ns / 2)
        init = Box.from_array(p.init_box) if p.init_box is not None else None
        if init is None and not Box.from_array(gt[0]).is_valid:
            raise DatasetError(f"rosbag: {p.gt_topic!r} gives no target box for the first image; give init_box")
        name = p.sequence or (path.stem if path.is_file() else path.name)
        return [Sequence(name=name, groundtruth=gt, fps=fps, loader=BagFrames(path, p.image_topic, receive),
                         init=init, meta={"source": str(path), "image_stamps_ns": stamps})]


def match_ground_truth(image_stamps: np.ndarray, image_receive: np.ndarray, gt_msgs: list, tol_ns: float) -> np.ndarray:
    """(N, 4) ground truth per image: each message goes to the image of the nearest time (header
    stamps when the message has a header, else receive times) within ``tol_ns``; NaN elsewhere."""
    gt = np.full((len(image_stamps), 4), np.nan)
    for (t, has_header), box in gt_msgs:
        times = image_stamps if has_header else image_receive
        i = int(np.argmin(np.abs(times - t)))
        if abs(int(times[i]) - t) <= tol_ns:
            gt[i] = box
    bad = ~np.isfinite(gt).all(axis=1) | (gt[:, 2] <= 0) | (gt[:, 3] <= 0)
    gt[bad] = np.nan
    return gt


@hookimpl
def mata_eval_datasets() -> list[type]:
    return [RosbagDataset]
