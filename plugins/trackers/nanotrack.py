"""NanoTrack v2 (HonglinChu/SiamTrackers) through an ONNX backend: backbone + head, with our own
crop, pre- and post-processing so the MATA prior can move the search region and the 16x16
foreground-probability map is exposed.

Pre/post-processing follows ``cv2.TrackerNano`` (OpenCV ``modules/video/src/tracking/
tracker_nano.cpp``), a port of the SiamRPN++/pysot tracking loop: exemplar 127 px from a square
of side ``int(sqrt((w + p)(h + p)))``, ``p = (w + h) / 2``; search 255 px from a square twice
that side (OpenCV's integer ``255 / 127``); padding with the image mean; RGB blob with raw
0..255 values; softmax foreground score, scale/ratio penalty ``exp(-(r s - 1) k)``, cosine window
blended with weight 0.455, size updated with learning rate ``penalty x score x 0.37``.
``scale_penalty_reference='opencv'`` keeps a quirk of OpenCV's port (the scale penalty divides by
the size computed from the target *position*); ``'size'`` is pysot's original (the target size
in search-crop pixels). These are OpenCV 5.0's; ``opencv_port: "5.1"`` reproduces OpenCV 5.1,
which fixed all three (float ``255 / 127``, untruncated sum, the target size as reference).

Confidence: the paper's window score extended to 2-D (section 2.1, last paragraph) on the
foreground-probability map (normalised as a PMF, square window around its peak); the raw peak
probability and OpenCV's penalised tracking score are in ``extra``.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Box, TrackerOutput

from .crop import usable_prior
from .model_files import resolve_model
from .window_score import check_window_alpha, map_window_score

EXEMPLAR = 127
INSTANCE = 255
STRIDE = 16
SCORE_SIZE = (INSTANCE - EXEMPLAR) // STRIDE + 8   # 16, as in tracker_nano.cpp


# --- ONNX input-shape relaxation --------------------------------------------------------------
# The published backbone declares a fixed 1x3x255x255 input but is fully convolutional: OpenCV's
# dnn reshapes it for the 127x127 exemplar on the fly, onnxruntime refuses. Without the `onnx`
# package (not a dependency) we rewrite the few protobuf fields by hand: graph inputs/outputs get
# symbolic spatial dims and the stored intermediate shapes (value_info) are dropped. The file on
# disk is not touched; the relaxed copy is cached in the temp folder.

def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift = result = 0
    while True:
        b = buf[i]
        i += 1
        result |= (b & 0x7F) << shift
        if b < 0x80:
            return result, i
        shift += 7


def _enc_varint(v: int) -> bytes:
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _fields(buf: bytes) -> list[tuple[int, int, bytes]]:
    """Top-level protobuf fields as (number, wire type, raw value bytes without the key)."""
    out, i = [], 0
    while i < len(buf):
        key, i = _varint(buf, i)
        num, wt = key >> 3, key & 7
        if wt == 0:
            _, j = _varint(buf, i)
        elif wt == 1:
            j = i + 8
        elif wt == 2:
            n, i = _varint(buf, i)
            j = i + n
        elif wt == 5:
            j = i + 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wt} (not an ONNX file?)")
        out.append((num, wt, buf[i:j]))
        i = j
    return out


def _emit(fields: list[tuple[int, int, bytes]]) -> bytes:
    parts = []
    for num, wt, val in fields:
        parts.append(_enc_varint((num << 3) | wt))
        if wt == 2:
            parts.append(_enc_varint(len(val)))
        parts.append(val)
    return b"".join(parts)


def _symbolic_spatial_dims(value_info: bytes, prefix: str) -> bytes:
    """ValueInfoProto with dims 2 and 3 of its tensor shape replaced by dim_params."""
    vi = _fields(value_info)
    for a, (n1, w1, type_proto) in enumerate(vi):
        if n1 != 2:
            continue
        tp = _fields(type_proto)
        for b, (n2, w2, tensor) in enumerate(tp):
            if n2 != 1:
                continue
            tt = _fields(tensor)
            for c, (n3, w3, shape) in enumerate(tt):
                if n3 != 2:
                    continue
                dims = _fields(shape)
                k = 0
                for d, (n4, w4, dim) in enumerate(dims):
                    if n4 != 1:
                        continue
                    if k in (2, 3):
                        dims[d] = (1, 2, _emit([(2, 2, f"{prefix}_{k}".encode())]))
                    k += 1
                tt[c] = (n3, w3, _emit(dims))
            tp[b] = (n2, w2, _emit(tt))
        vi[a] = (n1, w1, _emit(tp))
    return _emit(vi)


def relax_spatial_dims(model: bytes) -> bytes:
    """ONNX model bytes with symbolic H, W on graph inputs and outputs and no value_info."""
    top = _fields(model)
    for t, (num, wt, graph) in enumerate(top):
        if num != 7:  # ModelProto.graph
            continue
        fields = []
        for gnum, gwt, val in _fields(graph):
            if gnum == 13:          # GraphProto.value_info: stale fixed shapes, drop
                continue
            if gnum in (11, 12):    # input / output
                val = _symbolic_spatial_dims(val, "in" if gnum == 11 else "out")
            fields.append((gnum, gwt, val))
        top[t] = (num, wt, _emit(fields))
    return _emit(top)


def relaxed_copy(path: Path) -> Path:
    """Path of a cached copy of ``path`` with relaxed spatial dims (written once, atomically)."""
    data = path.read_bytes()
    digest = hashlib.sha256(data).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / f"mata_eval_{digest}_{path.name}"
    if not out.is_file():
        tmp = out.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_bytes(relax_spatial_dims(data))
        os.replace(tmp, out)
    return out


# --- tracker ------------------------------------------------------------------------------------

def size_measure(w, h):
    """SiamRPN 'sz': side of the square with the target plus context ``(w + h) / 2``."""
    pad = (w + h) * 0.5
    return np.sqrt((w + pad) * (h + pad))


class NanoTrack:
    """NanoTrack v2 (SiamTrackers) on ONNX Runtime/TensorRT; prior-aware; 2-D window-score confidence."""

    name = "nanotrack"
    label = "NanoTrack"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        backbone: str | None = param(None, "path to nanotrack_backbone_sim.onnx (or $MATA_NANOTRACK_BACKBONE)")
        head: str | None = param(None, "path to nanotrack_head_sim.onnx (or $MATA_NANOTRACK_HEAD)")
        backend: Literal["onnxruntime", "tensorrt", "torch"] = param("onnxruntime", "inference backend ('torch' runs `checkpoint`)")
        checkpoint: str | None = param(None, "torch backend: nanotrackv2.pth (loaded weights-only)")
        device: Literal["cpu", "cuda", "tensorrt"] = param("cpu", "ONNX Runtime device / provider; torch device "
                                                                   "(cpu or cuda) for the torch backend")
        threads: int = param(1, "ONNX Runtime intra-op threads (0 = library default)")
        window_influence: float = param(0.455, "cosine window weight (cv2.TrackerNano)")
        penalty_k: float = param(0.055, "scale/ratio change penalty")
        lr: float = param(0.37, "size update rate (times penalty x score)")
        context_amount: float = param(0.5, "context added around the target")
        window_alpha: float = param(0.125, "2-D window score: side = 2 round(alpha 16 / 2) + 1 cells (0.125 -> 3x3)")
        scale_penalty_reference: Literal["opencv", "size"] = param(
            "opencv", "scale penalty reference: 'opencv' = cv2.TrackerNano's (see opencv_port), 'size' = pysot's target size")
        opencv_port: Literal["5.0", "5.1"] = param(
            "5.0", "the cv2.TrackerNano reproduced: '5.0' (up to OpenCV 5.0) or '5.1' (search side 255/127 "
            "of the exemplar's, size sum not truncated, scale penalty against the target size)")
        opencv_rounding: bool = param(True, "report integer (truncated) boxes exactly like cv2.TrackerNano")

        def __post_init__(self) -> None:
            """window_alpha's range, checked when the experiment is loaded (not in a first frame)."""
            check_window_alpha("nanotrack", self.window_alpha, "the score map's side")

    def __init__(self, params: "NanoTrack.Params | None" = None):
        self.params = params or self.Params()
        if self.params.backend == "torch":
            if not self.params.checkpoint:
                raise ValueError("nanotrack: the torch backend needs `checkpoint` (nanotrackv2.pth)")
        else:
            files = self.model_files(self.params)
            self._backbone_path, self._head_path = files["backbone"], files["head"]
        self._nets = None
        self._hann = cv2.createHanningWindow((SCORE_SIZE, SCORE_SIZE), cv2.CV_32F)
        grid = (np.arange(SCORE_SIZE) - SCORE_SIZE // 2) * STRIDE + INSTANCE // 2
        self._grid_x = np.tile(grid[None, :], (SCORE_SIZE, 1)).astype(np.float32)
        self._grid_y = self._grid_x.T.copy()
        self._pos: np.ndarray | None = None

    @classmethod
    def model_files(cls, params: "NanoTrack.Params") -> dict[str, Path]:
        """The weight files these parameters read: the torch checkpoint, or the ONNX backbone and
        head (YAML paths, else $MATA_NANOTRACK_BACKBONE / _HEAD, else the shared data's); a
        run's manifest records them and their sha256."""
        if params.backend == "torch":
            return {"checkpoint": Path(params.checkpoint).expanduser()} if params.checkpoint else {}
        return {"backbone": resolve_model("nanotrack_backbone", params.backbone),
                "head": resolve_model("nanotrack_head", params.head)}

    def check(self) -> None:
        """Preflight: the model files were found (``__init__``); the backend can run here."""
        from .backends import BackendUnavailable, check_backend, check_device, check_inputs

        if self.params.backend == "torch":
            check_device("torch", self.params.device)
            if not Path(self.params.checkpoint).is_file():
                from .nanotrack_torch import SOURCE

                raise BackendUnavailable(f"nanotrack: checkpoint not found: {self.params.checkpoint} "
                                         f"(expected nanotrackv2.pth from {SOURCE})")
            return

        check_backend(self.params.backend, self.params.device)
        check_inputs(self._backbone_path, ("input",), "NanoTrack v2's backbone nanotrack_backbone_sim.onnx",
                     ((1, 48, SCORE_SIZE, SCORE_SIZE),))
        check_inputs(self._head_path, ("input1", "input2"), "NanoTrack v2's head nanotrack_head_sim.onnx",
                     ((1, 2, SCORE_SIZE, SCORE_SIZE), (1, 4, SCORE_SIZE, SCORE_SIZE)))

    def _networks(self):
        if self._nets is None and self.params.backend == "torch":
            from .nanotrack_torch import torch_runners

            self._nets = torch_runners(self.params.checkpoint, threads=self.params.threads, device=self.params.device)
        if self._nets is None:
            from .backends import open_onnx

            p = self.params
            crops = {"input": ((1, 3, EXEMPLAR, EXEMPLAR), (1, 3, INSTANCE, INSTANCE), (1, 3, INSTANCE, INSTANCE))}
            self._nets = (open_onnx(relaxed_copy(self._backbone_path), p.backend, p.device, p.threads, shapes=crops),
                          open_onnx(self._head_path, p.backend, p.device, p.threads))
        return self._nets

    def _subwindow(self, image: np.ndarray, pos: np.ndarray, original: int, out_size: int) -> np.ndarray:
        """tracker_nano.cpp getSubwindow: square of side ``original`` whose corner is
        ``int(pos) - (original + 1) // 2``, mean-colour padding, resized to ``out_size``; as an
        RGB float32 NCHW blob with raw 0..255 values."""
        if original < 1:
            raise ValueError(f"nanotrack: target too small to crop (window side {original})")
        H, W = image.shape[:2]
        c = (original + 1) // 2
        xmin = int(pos[0]) - c
        ymin = int(pos[1]) - c
        xmax, ymax = xmin + original - 1, ymin + original - 1
        left, top = max(0, -xmin), max(0, -ymin)
        right, bottom = max(0, xmax - W + 1), max(0, ymax - H + 1)
        if left or top or right or bottom:
            avg = cv2.mean(image)
            inside = image[max(ymin, 0):min(ymax + 1, H), max(xmin, 0):min(xmax + 1, W)]
            if inside.size == 0:
                crop = np.empty((original, original, 3), dtype=image.dtype)
                crop[...] = np.array(avg[:3]).round().astype(image.dtype)
            else:
                crop = cv2.copyMakeBorder(inside, top, bottom, left, right, cv2.BORDER_CONSTANT, value=avg)
        else:
            crop = image[ymin:ymax + 1, xmin:xmax + 1]
        crop = cv2.resize(crop, (out_size, out_size), interpolation=cv2.INTER_LINEAR)
        return np.ascontiguousarray(crop[:, :, ::-1].transpose(2, 0, 1)[None].astype(np.float32))

    def initialize(self, image: np.ndarray, box: Box) -> None:
        if not box.is_valid:
            raise ValueError(f"nanotrack: the initial box must have a positive finite size, got {box}")
        b = np.floor(box.as_array()) if self.params.opencv_rounding else box.as_array()
        self._pos = np.array([b[0] + b[2] * 0.5, b[1] + b[3] * 0.5], dtype=np.float32)
        self._size = np.array([b[2], b[3]], dtype=np.float32)
        self._img_hw = image.shape[:2]
        ca = self.params.context_amount
        s = self._size.sum()
        sz = int(math.sqrt((self._size[0] + ca * s) * (self._size[1] + ca * s)))
        backbone, _ = self._networks()
        self._zf = backbone({"input": self._subwindow(image, self._pos, sz, EXEMPLAR)})["output"]

    def track(self, image: np.ndarray, prior: tuple[float, float] | None = None) -> TrackerOutput:
        if self._pos is None:
            raise RuntimeError("nanotrack: track() called before initialize()")
        p = self.params
        # single precision throughout, like tracker_nano.cpp: int() truncations of the crop
        # corner then fall on the same side as OpenCV's
        f32 = np.float32
        # the prior is clamped into the image, the domain of cv2's own state: its scale penalty
        # takes the square root of a size computed from the position (see size_measure)
        prior = usable_prior(prior, self._size[0], self._size[1], *image.shape[:2], margin=0.0)
        if prior is not None:
            self._pos = np.array([prior[0], prior[1]], dtype=f32)
        port50 = p.opencv_port == "5.0"
        size_sum = self._size[0] + self._size[1]
        if port50:
            size_sum = f32(int(size_sum))                       # cv2 5.0 truncates the sum
        wc = self._size[0] + f32(p.context_amount) * f32(size_sum)
        hc = self._size[1] + f32(p.context_amount) * f32(size_sum)
        sz = np.sqrt(wc * hc)
        scale_z = f32(EXEMPLAR) / sz
        sx = sz * (f32(INSTANCE // EXEMPLAR) if port50 else f32(INSTANCE / EXEMPLAR))   # cv2 5.0: integer 255 / 127 = 2
        backbone, head = self._networks()
        crop_at = self._pos.copy()
        xf = backbone({"input": self._subwindow(image, crop_at, int(sx), INSTANCE)})["output"]
        out = head({"input1": self._zf, "input2": xf})
        cls = np.asarray(out["output1"], dtype=f32).reshape(2, SCORE_SIZE, SCORE_SIZE)
        loc = np.asarray(out["output2"], dtype=f32).reshape(4, SCORE_SIZE, SCORE_SIZE)
        e = np.exp(cls - cls.max(axis=0, keepdims=True))
        score = e[1] / (e[0] + e[1])

        x1, y1 = self._grid_x - loc[0], self._grid_y - loc[1]
        x2, y2 = self._grid_x + loc[2], self._grid_y + loc[3]
        pw, ph = x2 - x1, y2 - y1
        scaled = self._size * scale_z
        if p.scale_penalty_reference == "opencv" and port50:
            reference = size_measure(self._pos[0], self._pos[1])
        else:
            reference = size_measure(scaled[0], scaled[1])
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            sc = size_measure(pw, ph) / reference
            sc = np.maximum(sc, f32(1) / sc)
            rc = (scaled[0] / scaled[1]) / (pw / ph)
            rc = np.maximum(rc, f32(1) / rc)
            penalty = np.exp((rc * sc - f32(1)) * f32(p.penalty_k) * f32(-1))
        pscore = penalty * score
        pscore = pscore * f32(1.0 - p.window_influence) + self._hann * f32(p.window_influence)
        pscore = np.where(np.isfinite(pscore), pscore, -np.inf)
        iy, ix = np.unravel_index(int(np.argmax(pscore)), pscore.shape)

        cx_s = (x1[iy, ix] + x2[iy, ix]) / f32(2)
        cy_s = (y1[iy, ix] + y2[iy, ix]) / f32(2)
        lr = penalty[iy, ix] * score[iy, ix] * f32(p.lr)
        H, W = image.shape[:2]
        res_x = self._pos[0] + (cx_s - f32(INSTANCE // 2)) / scale_z
        res_y = self._pos[1] + (cy_s - f32(INSTANCE // 2)) / scale_z
        res_w = pw[iy, ix] / scale_z * lr + (f32(1) - lr) * self._size[0]
        res_h = ph[iy, ix] / scale_z * lr + (f32(1) - lr) * self._size[1]
        res_x, res_y = min(max(res_x, f32(0)), f32(W)), min(max(res_y, f32(0)), f32(H))
        res_w, res_h = min(max(res_w, f32(10)), f32(W)), min(max(res_h, f32(10)), f32(H))
        if not all(np.isfinite([res_x, res_y, res_w, res_h])):
            res_x, res_y, (res_w, res_h) = self._pos[0], self._pos[1], self._size
        self._pos = np.array([res_x, res_y], dtype=f32)
        self._size = np.array([res_w, res_h], dtype=f32)
        if p.opencv_rounding:   # cv2: Rect(int(x - w/2), int(y - h/2), int(w), int(h))
            box = Box(float(int(res_x - res_w / f32(2))), float(int(res_y - res_h / f32(2))),
                      float(int(res_w)), float(int(res_h)))
        else:
            box = Box.from_center(float(res_x), float(res_y), float(res_w), float(res_h))
        return TrackerOutput(
            box=box,
            confidence=float(np.clip(map_window_score(score, p.window_alpha), 0.0, 1.0)),
            score_map=score.astype(np.float32),
            extra={"peak": float(score.max()), "tracking_score": float(pscore[iy, ix]),
                   # the search crop of _subwindow: side int(sx), corner int(pos) - (side + 1) // 2
                   "search_x": float(int(crop_at[0]) - (int(sx) + 1) // 2),
                   "search_y": float(int(crop_at[1]) - (int(sx) + 1) // 2),
                   "search_w": float(int(sx)), "search_h": float(int(sx))},
        )


@hookimpl
def mata_eval_trackers():
    return [NanoTrack]
