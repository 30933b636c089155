"""VitTrack (OpenCV model zoo, 2023sep) through an ONNX backend, with our own crop, pre- and
post-processing so the MATA prior can move the search region and the 16x16 score map is exposed.

Pre/post-processing follows ``cv2.TrackerVit`` (OpenCV ``modules/video/src/tracking/
tracker_vit.cpp``): template = square crop of side ``ceil(sqrt(w h) * 2)`` resized to 128,
search = side ``ceil(sqrt(w h) * 4)`` resized to 256, zero padding outside the image; blob =
``(pixel - 255 mean) / (255 std)`` with the ImageNet mean/std applied to the channels **as
stored (BGR)**, with OpenCV's per-channel scale, see :func:`blob_scale`; the score map is
multiplied by a centred 16x16 Hann window and its argmax cell gives the box
``((i + offset) / 16, size)`` in crop units. With ``opencv_rounding`` the state is kept as
OpenCV's integer rectangle (floor), which is what parity with ``cv2.TrackerVit`` needs on
10-pixel targets. ``opencv_port``: the release reproduced; OpenCV 5.1 changed the blob scale to
element-wise, cuts the box to the image and keeps every side at 10 px or more
(docs/decisions/trackers.md).

Confidence (``confidence``): by default the network's own score, the sigmoid peak of the score
map, as the paper does for a tracker whose output map is too coarse for its window score
(section 2.1: L294 keeps OSTrack's score, L309-311); ``window`` is the paper's window score
extended to 2-D (last paragraph of 2.1) on the 16x16 map, measured worse (docs/mata.md). When
the Hann-weighted peak is below ``score_threshold`` the tracker found nothing: it reports
confidence 0 and ``extra['found'] = 0`` with its previous box, never the search centre as a box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Box, TrackerOutput

from .crop import crop_square, usable_prior
from .model_files import resolve_model
from .window_score import check_window_alpha, map_window_score

_MEAN_RGB = np.array([0.485, 0.456, 0.406])
_STD_RGB = np.array([0.229, 0.224, 0.225])
_FEAT = 16


def installed_opencv_port() -> str:
    """The ``opencv_port`` whose boxes the installed OpenCV's cv2.TrackerVit and cv2.TrackerNano
    give (5.1 changed both: docs/decisions/trackers.md), for parity checks against them."""
    return "5.1" if tuple(int(v) for v in cv2.__version__.split(".")[:2]) >= (5, 1) else "5.0"


def blob_scale(normalisation: str, opencv_port: str = "5.0") -> tuple[np.ndarray, np.ndarray, bool]:
    """Per-channel ``(mean, scale, swap_rb)`` with ``blob = (pixel - mean) * scale``.

    ``opencv``: what ``cv2.TrackerVit`` computes, on the BGR channels as stored with the RGB
    means subtracted in B, G, R order. It sets ``scalefactor = (1.0 / std) / 255`` on a
    ``cv::Scalar``; up to OpenCV 5.0 (``opencv_port`` "5.0") ``double / Scalar`` is a
    *quaternion* inverse, ``conj(s) / |s|^2``, so the scale is ``(s0, -s1, -s2) / (|s|^2 255)``;
    from 5.1 it is element-wise, ``1 / (s 255)``. Both verified against the cv2 tracking score
    (tests/test_trackers_onnx.py). ``imagenet``: the textbook ImageNet normalisation on RGB,
    ``(pixel / 255 - mean) / std``.
    """
    mean = (_MEAN_RGB * 255.0).astype(np.float32)
    if normalisation == "opencv" and opencv_port == "5.0":
        scale = np.array([_STD_RGB[0], -_STD_RGB[1], -_STD_RGB[2]]) / (np.sum(_STD_RGB ** 2) * 255.0)
        return mean, scale.astype(np.float32), False
    if normalisation in ("opencv", "imagenet"):
        return mean, (1.0 / (_STD_RGB * 255.0)).astype(np.float32), normalisation == "imagenet"
    raise ValueError(f"vittrack: normalisation must be 'opencv' or 'imagenet', got {normalisation!r}")


def _opencv51_box(box: np.ndarray, height: int, width: int) -> np.ndarray:
    """What cv2.TrackerVit 5.1 makes of a box (x, y, w, h): cut to the image, then each side at
    least 10 px, moved back inside the image where that makes it stick out (found against cv2
    5.1 on 147 boxes at the four image borders, docs/decisions/trackers.md)."""
    x0, y0 = max(box[0], 0.0), max(box[1], 0.0)
    w, h = min(box[0] + box[2], width) - x0, min(box[1] + box[3], height) - y0
    x0, y0 = min(x0, width - 10.0), min(y0, height - 10.0)
    return np.array([x0, y0, max(min(w, width - x0), 10.0), max(min(h, height - y0), 10.0)])


def hann_centered(n: int) -> np.ndarray:
    """OSTrack/OpenCV 'centered' Hann window: ``0.5 (1 - cos(2 pi k / (n + 1)))``, k = 1..n."""
    k = np.arange(1, n + 1, dtype=np.float64)
    return (0.5 * (1.0 - np.cos(2.0 * np.pi * k / (n + 1)))).astype(np.float32)


def to_blob(patch_bgr: np.ndarray, size: int, normalisation: str = "opencv", opencv_port: str = "5.0") -> np.ndarray:
    """Resize to ``size`` (bilinear) and normalise (see :func:`blob_scale`), NCHW float32."""
    if patch_bgr.shape[:2] != (size, size):
        patch_bgr = cv2.resize(patch_bgr, (size, size), interpolation=cv2.INTER_LINEAR)
    mean, scale, swap = blob_scale(normalisation, opencv_port)
    if swap:
        patch_bgr = patch_bgr[:, :, ::-1]
    blob = (patch_bgr.astype(np.float32) - mean) * scale
    return np.ascontiguousarray(blob.transpose(2, 0, 1)[None])


class VitTrack:
    """VitTrack (OpenCV zoo) on ONNX Runtime/TensorRT; prior-aware; sigmoid-peak confidence."""

    name = "vittrack"
    label = "VitTrack"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        model: str | None = param(None, "path to object_tracking_vittrack_2023sep.onnx (or $MATA_VITTRACK_ONNX)")
        backend: Literal["onnxruntime", "tensorrt"] = param("onnxruntime", "inference backend")
        device: Literal["cpu", "cuda", "tensorrt"] = param("cpu", "ONNX Runtime device / provider")
        threads: int = param(1, "ONNX Runtime intra-op threads (0 = library default)")
        template_factor: float = param(2.0, "template crop side relative to sqrt(w h)")
        search_factor: float = param(4.0, "search crop side relative to sqrt(w h)")
        confidence: Literal["peak", "window"] = param(
            "peak", "confidence: the score map's sigmoid peak (the tracker's own) or the 2-D window score")
        window_alpha: float = param(0.125, "2-D window score: side = 2 round(alpha 16 / 2) + 1 cells (0.125 -> 3x3)")
        score_threshold: float = param(0.2, "hold the last box when the Hann-weighted peak is below (cv2 default)")
        opencv_rounding: bool = param(True, "keep integer (floored) boxes exactly like cv2.TrackerVit")
        normalisation: Literal["opencv", "imagenet"] = param(
            "opencv", "input normalisation: 'opencv' = exactly cv2.TrackerVit's blob, 'imagenet' = RGB mean/std")
        opencv_port: Literal["5.0", "5.1"] = param(
            "5.0", "the cv2.TrackerVit reproduced: '5.0' (up to OpenCV 5.0: the zoo's published scores) or "
            "'5.1' (element-wise blob scale, boxes cut to the image, at least 10 px a side)")

        def __post_init__(self) -> None:
            """window_alpha's range, checked when the experiment is loaded (not in a first frame)."""
            check_window_alpha("vittrack", self.window_alpha, "the score map's side")

    def __init__(self, params: "VitTrack.Params | None" = None):
        self.params = params or self.Params()
        self._path = self.model_files(self.params)["model"]   # fails early, naming the file
        self._run = None
        self._hann = np.outer(hann_centered(_FEAT), hann_centered(_FEAT))
        self._box: np.ndarray | None = None

    @classmethod
    def model_files(cls, params: "VitTrack.Params") -> dict[str, Path]:
        """The weight file these parameters read: the YAML path, else $MATA_VITTRACK_ONNX, else the
        shared data's (a run's manifest records it and its sha256)."""
        return {"model": resolve_model("vittrack", params.model)}

    def check(self) -> None:
        """Preflight: the model file was found (``__init__``) and is VitTrack's; the backend can
        run here."""
        from .backends import check_backend, check_inputs

        check_backend(self.params.backend, self.params.device)
        check_inputs(self._path, ("template", "search"), "VitTrack's object_tracking_vittrack_2023sep.onnx",
                     ((1, 1, _FEAT, _FEAT), (1, 2, _FEAT, _FEAT), (1, 2, _FEAT, _FEAT)))

    def _net(self):
        if self._run is None:
            from .backends import open_onnx

            p = self.params
            self._run = open_onnx(self._path, p.backend, p.device, p.threads)
        return self._run

    def _crop(self, image: np.ndarray, box: np.ndarray, factor: float) -> tuple[np.ndarray, int, int, int]:
        """Square crop around ``box``; returns (patch, x1, y1, crop_sz) in image pixels."""
        x, y, w, h = box
        if self.params.opencv_rounding:   # integer arithmetic of tracker_vit.cpp::crop_image
            x, y, w, h = (int(v) for v in (x, y, w, h))
            crop_sz = math.ceil(math.sqrt(w * h) * factor)
            x1 = x + int((w - crop_sz) / 2)      # C++ int division truncates toward zero
            y1 = y + int((h - crop_sz) / 2)
        else:
            crop_sz = math.ceil(math.sqrt(w * h) * factor)
            x1 = round(x + 0.5 * w - 0.5 * crop_sz)
            y1 = round(y + 0.5 * h - 0.5 * crop_sz)
        if crop_sz < 1:
            raise ValueError(f"vittrack: box {tuple(box)} is too small to crop")
        return crop_square(image, x1, y1, crop_sz, crop_sz), x1, y1, crop_sz

    def initialize(self, image: np.ndarray, box: Box) -> None:
        if not box.is_valid:
            raise ValueError(f"vittrack: the initial box must have a positive finite size, got {box}")
        b = box.as_array()
        if self.params.opencv_rounding:
            b = np.floor(b)
        patch, _, _, _ = self._crop(image, b, self.params.template_factor)
        self._template = to_blob(patch, 128, self.params.normalisation, self.params.opencv_port)
        self._box = b

    def track(self, image: np.ndarray, prior: tuple[float, float] | None = None) -> TrackerOutput:
        if self._box is None:
            raise RuntimeError("vittrack: track() called before initialize()")
        p = self.params
        x, y, w, h = self._box
        region = self._box.copy()
        prior = usable_prior(prior, w, h, *image.shape[:2])
        if prior is not None:
            region[0], region[1] = prior[0] - w / 2.0, prior[1] - h / 2.0
            if p.opencv_rounding:
                region = np.floor(region)
        patch, x1, y1, crop_sz = self._crop(image, region, p.search_factor)
        out = self._net()({"template": self._template, "search": to_blob(patch, 256, p.normalisation, p.opencv_port)})
        score = np.asarray(out["output1"], dtype=np.float32).reshape(_FEAT, _FEAT)
        size = np.asarray(out["output2"], dtype=np.float32).reshape(2, _FEAT, _FEAT)
        offset = np.asarray(out["output3"], dtype=np.float32).reshape(2, _FEAT, _FEAT)
        weighted = score * self._hann
        iy, ix = np.unravel_index(int(np.argmax(weighted)), weighted.shape)
        tracking_score = float(weighted[iy, ix])
        found = False
        if tracking_score >= p.score_threshold:
            cx = (ix + offset[0, iy, ix]) / _FEAT
            cy = (iy + offset[1, iy, ix]) / _FEAT
            bw, bh = size[0, iy, ix], size[1, iy, ix]
            nb = np.array([(cx - bw / 2) * crop_sz + x1, (cy - bh / 2) * crop_sz + y1,
                           bw * crop_sz, bh * crop_sz], dtype=np.float64)
            if p.opencv_rounding:
                nb = np.floor(nb)
            if p.opencv_port == "5.1":
                nb = _opencv51_box(nb, *image.shape[:2])
            found = bool(nb[2] >= 1 and nb[3] >= 1 and np.all(np.isfinite(nb)))
        reported = nb if found else self._box          # nothing found: the previous box, confidence 0
        if found:
            self._box = nb
        elif prior is not None:
            self._box = region   # keep searching where the estimator expects the target
        peak = float(score.max())
        if not found:
            confidence = 0.0
        elif p.confidence == "peak":
            confidence = peak
        else:
            confidence = map_window_score(score, p.window_alpha) if peak > 0 else 0.0
        return TrackerOutput(
            box=Box.from_array(reported),
            confidence=float(np.clip(confidence, 0.0, 1.0)),
            score_map=score,
            extra={"peak": peak, "tracking_score": tracking_score, "found": float(found),
                   "search_x": float(x1), "search_y": float(y1), "search_w": float(crop_sz), "search_h": float(crop_sz)},
        )


@hookimpl
def mata_eval_trackers():
    return [VitTrack]
