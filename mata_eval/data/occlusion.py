"""Occlusion augmentation (paper section 3.2; `mata-eval augment`, or on the fly at load time).

For each occlusion event only the shape family and the start/end frames are hand-set
(:class:`OcclusionParams`); everything else is drawn from a generator seeded by (experiment seed,
sequence name): start and end positions outside the image, a few hit points on the object's
ground-truth track, a per-frame trajectory by linear interpolation through them with a small
acceleration jitter, one occluder object per event (rectangle, ellipse, circle, blob, irregular
polygon or stripe) scaled to the object size, its colour and alpha. The occluder is
alpha-blended onto the frame; the ground truth is left unchanged. Every method compared under
the same seed sees the same occlusions.

:func:`augment_sequence` returns a new :class:`~mata_eval.core.sequence.Sequence` whose loader
composites the occluders when a frame is read (no frame is written: UAV123 is 13 GB), with the
per-frame fraction of the ground-truth box covered in ``meta["occlusion"]`` and the events in
``meta["occlusion_events"]``; :func:`write_augmented` writes an augmented copy in the UAV123
layout, with the per-frame metadata and a contact sheet per sequence.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Sequence as Seq

import cv2
import numpy as np

from ..core.errors import ConfigError
from ..core.params import param
from ..core.sequence import Sequence

SHAPES = ("rectangle", "ellipse", "circle", "blob", "polygon", "stripe")
ShapeName = Literal["rectangle", "ellipse", "circle", "blob", "polygon", "stripe"]

#: attribute added to a sequence where at least one augmented occluder covers the target
ATTRIBUTE = "AOC"

_SHIFT = 4  # fixed-point bits for cv2.fillPoly: vertices at 1/16 pixel


@dataclass(frozen=True)
class OcclusionParams:
    """Occlusion augmentation (paper 3.2). Hand-set: the shape family and the start/end frames of
    each event; the rest is drawn from the seeded generator within the ranges below."""

    events: list[dict] = param([], "hand-set events [{shape, start, end}], start/end as frame index (int) "
                                   "or fraction of the sequence (float in [0, 1]); empty: n_events "
                                   "evenly spaced events")
    n_events: int = param(2, "events per sequence when `events` is empty")
    shapes: list[str] = param(list(SHAPES), "shape families, event i uses shapes[i % len] when `events` is empty")
    duration: float = param(2.0, "seconds per event when `events` is empty")
    skip_start: int = param(10, "frames at the start never occluded (tracker initialisation)")
    size: tuple[float, float] = param((1.0, 2.0), "occluder size range, relative to the object size sqrt(w*h)")
    alpha: tuple[float, float] = param((0.85, 1.0), "opacity range of the occluder")
    hit_points: tuple[int, int] = param((1, 3), "range of the number of hit points on the ground-truth track")
    jitter: float = param(0.01, "acceleration jitter, std in object sizes per frame^2")

    def __post_init__(self) -> None:
        def fail(key: tuple, message: str) -> None:
            raise ConfigError("", ("occlusion",) + key, message)

        bad = [s for s in self.shapes if s not in SHAPES]
        if bad or not self.shapes:
            fail(("shapes",), f"unknown shape(s) {bad or '(empty list)'}; expected some of {', '.join(SHAPES)}")
        for i, e in enumerate(self.events):
            if not isinstance(e, dict) or set(e) - {"shape", "start", "end"} or not {"start", "end"} <= set(e):
                fail(("events", i), f"expected {{shape, start, end}} (start/end: frame index or fraction), got {e!r}")
            if e.get("shape", self.shapes[i % len(self.shapes)]) not in SHAPES:
                fail(("events", i, "shape"), f"expected one of {', '.join(SHAPES)}, got {e['shape']!r}")
            for key in ("start", "end"):
                v = e[key]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not 0 <= v <= 1) \
                        or (isinstance(v, int) and v < 0):
                    fail(("events", i, key), f"expected a frame index >= 0 (int) or a fraction in [0, 1] (float), "
                                             f"got {v!r}")
            if type(e["start"]) is type(e["end"]) and e["end"] < e["start"]:   # QA pass: dropped without a word
                fail(("events", i), f"ends before it starts: {e!r}")
        if self.n_events < 0:
            fail(("n_events",), f"expected >= 0, got {self.n_events}")
        if not 0 < self.duration < math.inf:
            fail(("duration",), f"expected seconds > 0, got {self.duration}")
        if self.skip_start < 0:
            fail(("skip_start",), f"expected frames >= 0, got {self.skip_start}")
        for i, e in enumerate(self.events):
            if isinstance(e["end"], int) and e["end"] < self.skip_start:
                fail(("events", i), f"ends at frame {e['end']}, within skip_start ({self.skip_start}: the first "
                                    "frames are never occluded); it would be dropped")
        if not 0 <= self.jitter < math.inf:
            fail(("jitter",), f"expected a standard deviation >= 0, got {self.jitter}")
        for key in ("size", "alpha", "hit_points"):
            lo, hi = getattr(self, key)
            if not 0 <= lo <= hi < math.inf or (key == "alpha" and hi > 1):
                fail((key,), f"expected a range [low, high] with 0 <= low <= high"
                             f"{' <= 1' if key == 'alpha' else ' (finite)'}, got {list(getattr(self, key))!r}")


@dataclass(frozen=True, eq=False)
class OcclusionEvent:
    """One occluder crossing the image from ``start`` to ``end`` (frames, inclusive).
    ``polygon``: (M, 2) outline relative to the centre; ``centres``: (end-start+1, 2) per-frame
    centre; ``hit_frames``/``hit_points``: where the track was aimed at the ground truth."""

    index: int
    shape: str
    start: int
    end: int
    polygon: np.ndarray
    centres: np.ndarray
    hit_frames: tuple[int, ...]
    hit_points: np.ndarray
    alpha: float
    colour: tuple[float, float, float]
    texture_seed: int = 0

    def active(self, k: int) -> bool:
        return self.start <= k <= self.end

    def outline(self, k: int) -> np.ndarray:
        """The occluder's polygon in image pixels at frame k (must be active)."""
        return self.polygon + self.centres[k - self.start]

    def to_json(self) -> dict:
        return {"index": self.index, "shape": self.shape, "start": self.start, "end": self.end,
                "alpha": self.alpha, "colour": list(self.colour), "texture_seed": self.texture_seed,
                "hit_frames": list(self.hit_frames),
                "hit_points": self.hit_points.tolist(), "polygon": self.polygon.tolist(),
                "centres": self.centres.tolist()}


def occlusion_seed(seed: int, name: str) -> int:
    """Per-sequence seed from (experiment seed, sequence name): independent of sequence order."""
    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, zlib.crc32(name.encode()), 0x0CC]).generate_state(1)[0])


# --- planning (pure) ----------------------------------------------------------------------------

def _shape_polygon(shape: str, S: float, rng: np.random.Generator) -> np.ndarray:
    """Outline (M, 2) of a shape family around the origin, scaled to size S (pixels)."""
    def rot(p: np.ndarray, a: float) -> np.ndarray:
        c, s = math.cos(a), math.sin(a)
        return p @ np.array([[c, s], [-s, c]])

    th = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    if shape == "rectangle":
        w, h = S * rng.uniform(0.6, 1.4, 2)
        p = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2
        return rot(p, rng.uniform(0, np.pi))
    if shape == "ellipse":
        a, b = S * rng.uniform(0.5, 0.8), S * rng.uniform(0.25, 0.45)
        return rot(np.stack([a * np.cos(th), b * np.sin(th)], 1), rng.uniform(0, np.pi))
    if shape == "circle":
        r = S * rng.uniform(0.45, 0.7)
        return np.stack([r * np.cos(th), r * np.sin(th)], 1)
    if shape == "blob":
        r = S * rng.uniform(0.45, 0.65) * (1 + sum(rng.uniform(0, 0.18) * np.sin(j * th + rng.uniform(0, 2 * np.pi))
                                                   for j in (2, 3, 4)))
        return np.stack([r * np.cos(th), r * np.sin(th)], 1)
    if shape == "polygon":
        m = int(rng.integers(5, 10))
        a = np.sort(rng.uniform(0, 2 * np.pi, m))
        r = S * rng.uniform(0.35, 0.75, m)
        return np.stack([r * np.cos(a), r * np.sin(a)], 1)
    if shape == "stripe":
        L, w = S * rng.uniform(3.0, 5.0), S * rng.uniform(0.2, 0.4)
        p = np.array([[-L, -w], [L, -w], [L, w], [-L, w]]) / 2
        return rot(p, rng.uniform(0, np.pi))
    raise ValueError(f"unknown occluder shape {shape!r}; expected one of {', '.join(SHAPES)}")


def _outside_point(W: int, H: int, R: float, rng: np.random.Generator, side: int) -> np.ndarray:
    """A centre on the given side (0 left, 1 top, 2 right, 3 bottom) far enough outside the image
    that a shape of radius R does not touch it."""
    m = R + 2.0 + rng.uniform(0, 0.5 * R)
    if side == 0:
        return np.array([-m, rng.uniform(0, H)])
    if side == 1:
        return np.array([rng.uniform(0, W), -m])
    if side == 2:
        return np.array([W + m, rng.uniform(0, H)])
    return np.array([rng.uniform(0, W), H + m])


def _event_windows(n: int, fps: float, params: OcclusionParams) -> list[tuple[str, int, int]]:
    """Hand-set (shape, start, end) per event: from ``params.events`` or evenly spaced."""
    def frame(v) -> int:
        return int(round(v * (n - 1))) if isinstance(v, float) else int(v)

    out = []
    if params.events:
        for i, e in enumerate(params.events):
            out.append((e.get("shape", params.shapes[i % len(params.shapes)]), frame(e["start"]), frame(e["end"])))
    else:
        dur = max(2, int(round(params.duration * fps)))
        lo = min(params.skip_start, n - 1)
        for i in range(params.n_events):
            mid = lo + (n - lo) * (i + 1) / (params.n_events + 1)
            out.append((params.shapes[i % len(params.shapes)], int(round(mid - dur / 2)), int(round(mid + dur / 2))))
    clipped = []
    for shape, s, e in out:
        s, e = max(s, min(params.skip_start, n - 1), 0), min(e, n - 1)
        if e - s >= 1:
            clipped.append((shape, s, e))
    return clipped


def plan_occlusions(groundtruth: np.ndarray, image_size: tuple[int, int], params: OcclusionParams,
                    seed: int, fps: float = 30.0) -> list[OcclusionEvent]:
    """The occlusion events of one sequence (paper 3.2). Pure: depends only on the arguments.
    ``image_size`` is ``(width, height)``; ``seed`` the per-sequence seed (:func:`occlusion_seed`)."""
    gt = np.asarray(groundtruth, float)
    n = len(gt)
    W, H = int(image_size[0]), int(image_size[1])
    rng = np.random.default_rng(seed)
    valid = np.all(np.isfinite(gt), axis=1) & (gt[:, 2] > 0) & (gt[:, 3] > 0)
    sizes = np.sqrt(gt[valid, 2] * gt[valid, 3])
    default_size = float(np.median(sizes)) if len(sizes) else 0.1 * min(W, H)
    events = []
    for idx, (shape, start, end) in enumerate(_event_windows(n, fps, params)):
        window = np.arange(start, end + 1)
        inner = window[1:-1][valid[window[1:-1]]] if len(window) > 2 else window[:0]
        obj = float(np.median(sizes_w)) if len(sizes_w := np.sqrt(gt[inner, 2] * gt[inner, 3])) else default_size
        S = obj * rng.uniform(*params.size)
        poly = _shape_polygon(shape, S, rng)
        R = float(np.linalg.norm(poly, axis=1).max())
        side0 = int(rng.integers(4))
        side1 = int((side0 + rng.integers(1, 4)) % 4)
        p0, p1 = _outside_point(W, H, R, rng, side0), _outside_point(W, H, R, rng, side1)
        k = int(rng.integers(params.hit_points[0], params.hit_points[1] + 1))
        k = min(k, len(inner))
        hit_frames = np.sort(rng.choice(inner, size=k, replace=False)) if k else np.zeros(0, int)
        centres_gt = gt[hit_frames, :2] + gt[hit_frames, 2:] / 2
        hits = centres_gt + rng.uniform(-0.25, 0.25, (k, 2)) * gt[hit_frames, 2:]
        t_way = np.concatenate([[start], hit_frames, [end]]).astype(float)
        p_way = np.vstack([p0, hits.reshape(-1, 2), p1])
        path = np.stack([np.interp(window, t_way, p_way[:, d]) for d in (0, 1)], axis=1)
        # Acceleration jitter: double integral of white noise, minus its own piecewise-linear
        # interpolant through the waypoints, so start/end stay outside and the hits stay exact.
        acc = rng.normal(0, params.jitter * obj, (len(window), 2))
        wobble = np.cumsum(np.cumsum(acc, axis=0), axis=0)
        at_way = np.stack([np.interp(t_way, window, wobble[:, d]) for d in (0, 1)], axis=1)
        wobble -= np.stack([np.interp(window, t_way, at_way[:, d]) for d in (0, 1)], axis=1)
        colour = tuple(float(c) for c in rng.uniform(10, 90, 3) + np.array([0, rng.uniform(0, 60), 0]))
        events.append(OcclusionEvent(idx, shape, int(start), int(end), poly, path + wobble,
                                     tuple(int(f) for f in hit_frames), hits.reshape(-1, 2),
                                     float(rng.uniform(*params.alpha)), colour, int(rng.integers(2**31))))
    return events


# --- masks and compositing ------------------------------------------------------------------------

def _polygon_mask(poly: np.ndarray, x0: int, y0: int, w: int, h: int, out: np.ndarray) -> None:
    """OR into ``out`` (h, w) the pixels of ``[x0, x0+w) x [y0, y0+h)`` whose centre (i + 0.5)
    lies inside ``poly``. The polygon is rasterised in its own bounding box, where it is never
    clipped, so the result does not depend on the window asked for."""
    bx0, by0 = np.floor(poly.min(0)).astype(int) - 1
    bx1, by1 = np.ceil(poly.max(0)).astype(int) + 2
    ix0, iy0, ix1, iy1 = max(bx0, x0), max(by0, y0), min(bx1, x0 + w), min(by1, y0 + h)
    if ix1 <= ix0 or iy1 <= iy0:
        return
    canvas = np.zeros((by1 - by0, bx1 - bx0), np.uint8)
    pts = np.round((poly - [bx0 + 0.5, by0 + 0.5]) * (1 << _SHIFT)).astype(np.int32)
    cv2.fillPoly(canvas, [pts], 1, cv2.LINE_8, shift=_SHIFT)
    out[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0] |= canvas[iy0 - by0:iy1 - by0, ix0 - bx0:ix1 - bx0]


def occluder_mask(events: Seq[OcclusionEvent], k: int, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """(h, w) uint8 0/1 mask of the occluders active at frame k over the pixel rectangle
    ``[x0, x0+w) x [y0, y0+h)``: a pixel is covered when its centre lies inside an occluder."""
    mask = np.zeros((max(h, 0), max(w, 0)), np.uint8)
    if mask.size == 0:
        return mask
    for e in events:
        if e.active(k):
            _polygon_mask(e.outline(k), x0, y0, w, h, mask)
    return mask


def occluder_texture(e: OcclusionEvent) -> np.ndarray:
    """(S, S, 3) float32 appearance of an event's occluder around its centre: its colour with
    a vertical shading and smooth plus fine noise (an object, not a flat patch); cached."""
    R = float(np.linalg.norm(e.polygon, axis=1).max())
    return _texture(e.texture_seed, 2 * int(math.ceil(R)) + 10, e.colour)


@functools.lru_cache(maxsize=64)
def _texture(seed: int, side: int, colour: tuple[float, float, float]) -> np.ndarray:
    rng = np.random.default_rng(seed)
    smooth = cv2.GaussianBlur(rng.standard_normal((side, side), dtype=np.float32), (0, 0), max(1.0, side / 16))
    smooth *= 14.0 / (smooth.std() + 1e-6)
    fine = rng.standard_normal((side, side), dtype=np.float32) * 5.0
    shade = np.linspace(0.85, 1.15, side, dtype=np.float32)[:, None, None]
    tex = np.asarray(colour, np.float32)[None, None, :] * shade + (smooth + fine)[..., None]
    tex = np.clip(tex, 0, 255)
    tex.setflags(write=False)
    return tex


def composite(image: np.ndarray, events: Seq[OcclusionEvent], k: int) -> np.ndarray:
    """Frame k with the active occluders alpha-blended on (a new array; the input is untouched)."""
    out = image
    H, W = image.shape[:2]
    for e in events:
        if not e.active(k):
            continue
        poly = e.outline(k)
        x0, y0 = np.floor(poly.min(0)).astype(int) - 1
        x1, y1 = np.ceil(poly.max(0)).astype(int) + 2
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        if x1 <= x0 or y1 <= y0:
            continue
        m = occluder_mask([e], k, x0, y0, x1 - x0, y1 - y0).astype(bool)
        if not m.any():
            continue
        if out is image:
            out = image.copy()
        roi = out[y0:y1, x0:x1]
        # the occluder's own texture moves with it (integer-pixel placement); hard-edged mask,
        # uniform alpha
        tex = occluder_texture(e)
        c = e.centres[k - e.start]
        px0 = int(round(c[0])) - tex.shape[1] // 2
        py0 = int(round(c[1])) - tex.shape[0] // 2
        colour = tex[y0 - py0:y1 - py0, x0 - px0:x1 - px0]
        blended = roi * (1.0 - e.alpha) + colour * e.alpha
        roi[m] = np.clip(blended[m] + 0.5, 0, 255).astype(np.uint8)
    return out


def box_pixels(box: np.ndarray, W: int, H: int) -> tuple[int, int, int, int]:
    """Pixel rectangle ``(x0, y0, x1, y1)`` whose centres lie inside the box, clipped to the image."""
    x, y, w, h = box
    x0 = max(0, int(math.ceil(x - 0.5)))
    y0 = max(0, int(math.ceil(y - 0.5)))
    x1 = min(W, int(math.ceil(x + w - 0.5)))
    y1 = min(H, int(math.ceil(y + h - 0.5)))
    return x0, y0, x1, y1


def covered_fraction(events: Seq[OcclusionEvent], groundtruth: np.ndarray,
                     image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the fraction of the ground-truth box's pixels covered by an occluder (NaN where
    the box is absent), and per event, the largest fraction it covers alone."""
    gt = np.asarray(groundtruth, float)
    W, H = image_size
    frac = np.full(len(gt), np.nan)
    peak = np.zeros(len(events))
    for k, box in enumerate(gt):
        if not (np.all(np.isfinite(box)) and box[2] > 0 and box[3] > 0):
            continue
        x0, y0, x1, y1 = box_pixels(box, W, H)
        n = max(0, x1 - x0) * max(0, y1 - y0)
        if n == 0:
            frac[k] = 0.0
            continue
        act = [e for e in events if e.active(k)]
        if not act:
            frac[k] = 0.0
            continue
        frac[k] = occluder_mask(act, k, x0, y0, x1 - x0, y1 - y0).sum() / n
        for e in act:
            peak[e.index] = max(peak[e.index], occluder_mask([e], k, x0, y0, x1 - x0, y1 - y0).sum() / n)
    return frac, peak


# --- sequences --------------------------------------------------------------------------------------

class OccludedLoader:
    """``k -> image`` of the base sequence with the occluders composited (picklable)."""

    def __init__(self, base: Sequence, events: list[OcclusionEvent]):
        self.base = base
        self.events = events

    def __call__(self, k: int) -> np.ndarray:
        return composite(self.base.image(k), self.events, k)


def image_size_of(sequence: Sequence) -> tuple[int, int]:
    """``(width, height)`` from ``meta["image_size"]`` or by reading frame 0."""
    size = sequence.meta.get("image_size") if sequence.meta else None
    if size is not None:
        return int(size[0]), int(size[1])
    h, w = sequence.image(0).shape[:2]
    return w, h


def augment_sequence(sequence: Sequence, params: OcclusionParams, seed: int) -> Sequence:
    """A new Sequence whose frames carry the occlusion events (composited when read; nothing is
    written). Ground truth unchanged; ``AOC`` added when an event covers the target;
    ``meta["occlusion"]``: (N,) covered fraction of the box; ``meta["occlusion_events"]``."""
    size = image_size_of(sequence)
    events = plan_occlusions(sequence.groundtruth, size, params, occlusion_seed(seed, sequence.name), sequence.fps)
    frac, peak = covered_fraction(events, sequence.groundtruth, size)
    attrs = sequence.attributes | ({ATTRIBUTE} if np.any(peak > 0) else frozenset())
    meta = {**dict(sequence.meta), "occlusion": frac, "occlusion_events": events,
            "occlusion_event_peak": peak, "image_size": size}
    return dataclasses.replace(sequence, loader=OccludedLoader(sequence, events), attributes=frozenset(attrs),
                               meta=meta)


# --- writing an augmented copy ----------------------------------------------------------------------

def contact_sheet(sequence: Sequence, n: int = 6, width: int = 1600) -> np.ndarray:
    """A grid of the ``n`` most occluded frames of an augmented sequence (GT box in green,
    frame number and covered fraction written on each), for a person to look at."""
    frac = np.asarray(sequence.meta.get("occlusion", np.zeros(len(sequence))), float)
    score = np.nan_to_num(frac, nan=-1.0)
    picked: list[int] = []
    for e in sequence.meta.get("occlusion_events", []):  # the most covered frame of each event
        k = e.start + int(np.argmax(score[e.start:e.end + 1]))
        if k not in picked and len(picked) < n:
            picked.append(k)
    for k in np.argsort(-score, kind="stable"):  # then the most covered frames, 5 frames apart
        if len(picked) >= min(n, len(sequence)):
            break
        if all(abs(int(k) - j) >= 5 for j in picked) or len(picked) + (len(sequence) - len(picked)) <= n:
            picked.append(int(k))
    picked = sorted(picked) or [0]
    cols = min(3, len(picked))
    rows = int(math.ceil(len(picked) / cols))
    tile_w = width // cols
    tiles = []
    for k in picked:
        img = sequence.image(k).copy()
        box = sequence.groundtruth[k]
        if np.all(np.isfinite(box)):
            x, y, w, h = box
            cv2.rectangle(img, (int(round(x)), int(round(y))), (int(round(x + w)), int(round(y + h))), (0, 255, 0), 2)
        scale = tile_w / img.shape[1]
        img = cv2.resize(img, (tile_w, max(1, int(round(img.shape[0] * scale)))), interpolation=cv2.INTER_AREA)
        label = f"{sequence.name} #{k + 1}  covered {frac[k]:.2f}" if np.isfinite(frac[k]) else f"#{k + 1}  no GT"
        cv2.rectangle(img, (0, 0), (tile_w, 30), (0, 0, 0), -1)
        cv2.putText(img, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(img)
    th = max(t.shape[0] for t in tiles)
    blank = np.zeros((th, tile_w, 3), np.uint8)
    tiles = [np.vstack([t, np.zeros((th - t.shape[0], tile_w, 3), np.uint8)]) for t in tiles]
    tiles += [blank] * (rows * cols - len(tiles))
    return np.vstack([np.hstack(tiles[r * cols:(r + 1) * cols]) for r in range(rows)])


def write_occlusion_metadata(folder: Path, seq: Sequence) -> None:
    """``<seq>.txt``: per-frame covered fraction (NaN where no box); ``<seq>.events.json``."""
    folder.mkdir(parents=True, exist_ok=True)
    frac = np.asarray(seq.meta["occlusion"], float)
    (folder / f"{seq.name}.txt").write_text("\n".join("NaN" if not np.isfinite(v) else f"{v:.4f}" for v in frac) + "\n")
    events = [dict(e.to_json(), peak_covered=float(p))
              for e, p in zip(seq.meta["occlusion_events"], seq.meta["occlusion_event_peak"])]
    (folder / f"{seq.name}.events.json").write_text(json.dumps(events))


def read_occlusion_metadata(folder: Path, name: str) -> tuple[np.ndarray, bool] | None:
    """What :func:`write_occlusion_metadata` wrote for sequence ``name`` in ``folder``: the
    per-frame covered fraction and whether an event covered the target (the AOC attribute,
    from the events' exact peaks), or None when nothing was written for it."""
    path = folder / f"{name}.txt"
    if not path.is_file():
        return None
    frac = np.array([float(v) for v in path.read_text().split()])
    events = folder / f"{name}.events.json"
    peaks = [e.get("peak_covered", 0.0) for e in json.loads(events.read_text())] if events.is_file() else frac
    return frac, bool(np.nansum(np.asarray(peaks, float) > 0))


def load_occlusion(root: str | Path, seq: str) -> np.ndarray:
    """Per-frame covered fraction written by :func:`write_augmented` (NaN where no box)."""
    folder = Path(root) / "anno" / "UAV123" / "occlusion"
    written = read_occlusion_metadata(folder, seq)
    if written is None:
        raise FileNotFoundError(f"occlusion metadata not found: {folder / f'{seq}.txt'} (written by `mata-eval augment`)")
    return written[0]


def write_augmented(sequences: Seq[Sequence], out: str | Path, params: OcclusionParams, seed: int, *,
                    quality: int = 95, sheet_frames: int = 6, progress: bool = False,
                    overwrite: bool = False) -> list[str]:
    """Write augmented copies in the UAV123 layout (each sequence as its own video, frames from
    000001.jpg), ground truth unchanged, original attribute flags, per-frame occlusion metadata
    (``anno/UAV123/occlusion/``), true homographies when the input has them, and a contact sheet
    per sequence (``contact_sheets/<seq>.png``). Returns the names written."""
    from .synth import UAV123_ATTRIBUTES
    from .synth.writer import format_box, write_config_seqs

    out = Path(out)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise FileExistsError(f"{out} exists and is not empty; choose another folder or overwrite it (--force)")
    anno = out / "anno" / "UAV123"
    (anno / "att").mkdir(parents=True, exist_ok=True)
    (out / "contact_sheets").mkdir(parents=True, exist_ok=True)
    written = []
    for seq in sequences:
        aug = augment_sequence(seq, params, seed)
        folder = out / "data_seq" / "UAV123" / seq.name
        folder.mkdir(parents=True, exist_ok=True)
        for k in range(len(aug)):
            path = folder / f"{k + 1:06d}.jpg"
            if not cv2.imwrite(str(path), aug.image(k), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]):
                raise OSError(f"cannot write frame {path}")
        (anno / f"{seq.name}.txt").write_text("\n".join(format_box(b, exact=True) for b in seq.groundtruth) + "\n")
        (anno / "att" / f"{seq.name}.txt").write_text(
            ",".join("1" if a in seq.attributes else "0" for a in UAV123_ATTRIBUTES) + "\n")
        write_occlusion_metadata(anno / "occlusion", aug)
        if "homographies" in (seq.meta or {}):
            (anno / "homography").mkdir(exist_ok=True)
            np.savetxt(anno / "homography" / f"{seq.name}.txt", np.asarray(seq.meta["homographies"]).reshape(-1, 9),
                       fmt="%.10g", delimiter=",")
        cv2.imwrite(str(out / "contact_sheets" / f"{seq.name}.png"), contact_sheet(aug, sheet_frames))
        written.append(seq.name)
        if progress:
            print(f"  {seq.name}: {len(aug.meta['occlusion_events'])} events, "
                  f"{int(np.nansum(aug.meta['occlusion'] > 0))} occluded frames", flush=True)
    write_config_seqs(out, [(s.name, len(s)) for s in sequences])
    (out / "augment.json").write_text(json.dumps({"seed": seed, "occlusion": dataclasses.asdict(params),
                                                 "sequences": written,
                                                 # the source's frame rates, which the uav123 loader reads back
                                                 "fps": {s.name: float(s.fps) for s in sequences}}, indent=1))
    return written
