"""Rendering a planned sequence: every frame is ``cv2.warpPerspective`` of the pre-rendered
ground with ``G_k``, sprites are alpha-composited on top (trees last), and the ground truth (the
target's axis-aligned box clipped to the image, ``NaN`` rows when it is fully out of view or
fully occluded, as in UAV123), the exact inter-frame homographies and the attribute flags are
measured from what was drawn. In memory: :func:`render_sequence`."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable, Iterator

import cv2
import numpy as np

from . import texture as tex
from .attributes import ABSENT_BELOW, UAV123_ATTRIBUTES, attribute_flags
from .motion import Placed, plan_sequence, texture_size
from .spec import REF_WIDTH, SequenceSpec, make_spec


@dataclass(frozen=True, eq=False)
class RenderedSequence:
    """A rendered sequence. Unpacks as ``frames, groundtruth, homographies, attributes``.

    ``homographies[k]`` maps frame k-1 to frame k (h33 = 1; row 0 is the identity);
    ``ground_to_image[k]`` maps ground-texture pixels to frame k; ``visible[k]`` is the fraction
    of the target's area that is inside the image and not occluded; ``occluded[k]`` the fraction
    of its in-image area covered by occluders; ``flags`` the 12 UAV123 attribute flags."""

    spec: SequenceSpec
    frames: list[np.ndarray]
    groundtruth: np.ndarray
    homographies: np.ndarray
    attributes: frozenset[str]
    flags: tuple[int, ...]
    visible: np.ndarray
    occluded: np.ndarray
    ground_to_image: np.ndarray
    facts: dict = field(default_factory=dict)

    def __iter__(self) -> Iterator:
        return iter((self.frames, self.groundtruth, self.homographies, self.attributes))


def _sprite_to_ground(placed: Placed, k: int) -> np.ndarray:
    """3x3 affine map from sprite pixels to ground pixels at frame k."""
    sp = placed.sprite
    w, h = sp.size
    xy = placed.xy if placed.xy.ndim == 1 else placed.xy[k]
    a = float(placed.angle[min(k, len(placed.angle) - 1)])
    c, s = math.cos(a) * sp.pixel_size, math.sin(a) * sp.pixel_size
    return np.array([[c, -s, xy[0] - c * w / 2 + s * h / 2],
                     [s, c, xy[1] - s * w / 2 - c * h / 2],
                     [0, 0, 1.0]])


def _composite(frame: np.ndarray, sprite: tex.Sprite, M: np.ndarray):
    """Alpha-blend the (premultiplied) sprite warped by M (sprite px -> image px) onto frame, in
    the sprite's bounding rectangle only. Returns ``(x0, y0, alpha)`` or None when off-image."""
    Hh, Ww = frame.shape[:2]
    w, h = sprite.size
    corners = cv2.perspectiveTransform(np.array([[[0, 0], [w, 0], [w, h], [0, h]]], np.float64), M)[0]
    x0, y0 = np.floor(corners.min(0)).astype(int) - 1
    x1, y1 = np.ceil(corners.max(0)).astype(int) + 2
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, Ww), min(y1, Hh)
    if x1 <= x0 or y1 <= y0:
        return None
    T = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1.0]]) @ M
    warped = cv2.warpPerspective(sprite.bgra, T, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    a = warped[..., 3].astype(np.float32) * (1.0 / 255.0)
    roi = frame[y0:y1, x0:x1]
    roi[:] = np.clip(roi * (1.0 - a[..., None]) + warped[..., :3] + 0.5, 0, 255).astype(np.uint8)
    return x0, y0, a


def _projected_outline(placed: Placed, G: np.ndarray, k: int) -> np.ndarray:
    M = G @ _sprite_to_ground(placed, k)
    return cv2.perspectiveTransform(placed.sprite.outline[None].astype(np.float64), M)[0]


_TEXTURES: dict[tuple[int, int], np.ndarray] = {}


def ground_texture(texture_seed: int, size: int) -> np.ndarray:
    """The ground texture of a seed (cached per process: suites share a few grounds)."""
    key = (int(texture_seed), int(size))
    if key not in _TEXTURES:
        if len(_TEXTURES) >= 2:
            _TEXTURES.pop(next(iter(_TEXTURES)))
        _TEXTURES[key] = tex.ground_texture(size, np.random.default_rng(texture_seed))
    return _TEXTURES[key]


def render(spec: SequenceSpec, sink: Callable[[int, np.ndarray], None]) -> RenderedSequence:
    ground = ground_texture(spec.texture_seed, texture_size(spec.width))
    plan, events = plan_sequence(spec, ground)
    n, W, H = spec.n_frames, spec.width, spec.height
    s = W / REF_WIDTH
    gt_full = np.full((n, 4), np.nan)       # unclipped box of the projected silhouette
    in_image = np.zeros(n)                  # fraction of the silhouette area inside the image
    occluded = np.zeros(n)                  # fraction of the in-image part covered by trees
    distractor_in = np.zeros(n)             # best in-image fraction of a distractor
    contrast = np.full(n, np.nan)           # target vs surrounding colour distance (sampled)
    tree_centres = np.array([t.xy for t in plan.trees]).reshape(-1, 2)
    tree_reach = np.array([1.4 * t.radius + 4 for t in plan.trees])
    tree_sprites: dict[int, Placed] = {}

    for k in range(n):
        G = plan.G[k]
        frame = cv2.warpPerspective(ground, G, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        for d in plan.distractors:
            area = (abs(cv2.contourArea(_projected_outline(d, G, k).astype(np.float32))) * d.sprite.alpha_mass
                    / d.sprite.outline_area)
            r = _composite(frame, d.sprite, G @ _sprite_to_ground(d, k))
            if r is not None and area > 0:
                distractor_in[k] = max(distractor_in[k], float(r[2].sum()) / area)
        outline = _projected_outline(plan.target, G, k)
        lo, hi = outline.min(0), outline.max(0)
        # warpPerspective puts pixel i's centre at i; boxes use pixel i = [i, i+1) (UAV123)
        gt_full[k] = (lo[0] + 0.5, lo[1] + 0.5, hi[0] - lo[0], hi[1] - lo[1])
        # full silhouette area in image pixels: the sprite's alpha mass times the local area scale
        area = (abs(cv2.contourArea(outline.astype(np.float32))) * plan.target.sprite.alpha_mass
                / plan.target.sprite.outline_area)
        if spec.draw_target:
            tr = _composite(frame, plan.target.sprite, G @ _sprite_to_ground(plan.target, k))
        else:  # same scene, target not drawn: its would-be alpha is still measured
            scratch = np.zeros_like(frame)
            tr = _composite(scratch, plan.target.sprite, G @ _sprite_to_ground(plan.target, k))
        cover = None
        if tr is not None:
            tx0, ty0, ta = tr
            in_image[k] = float(ta.sum()) / max(area, 1e-9)
            cover = np.zeros_like(ta)
            if k % 10 == 0 and spec.draw_target:
                contrast[k] = _contrast(frame, tx0, ty0, ta)
        # Trees last (canopies are above everything); only those near the view are warped.
        if len(plan.trees):
            c = cv2.perspectiveTransform(tree_centres[None].astype(np.float64), G)[0]
            margin = 2.5 * tree_reach[:, None] + 10
            near = np.all((c > -margin) & (c < np.array([W, H]) + margin), axis=1)
            for i in np.flatnonzero(near):
                if i not in tree_sprites:
                    tree_sprites[i] = plan.trees[i].placed()
                r = _composite(frame, tree_sprites[i].sprite, G @ _sprite_to_ground(tree_sprites[i], k))
                if r is not None and cover is not None:
                    _accumulate_cover(cover, tx0, ty0, *r)
        if cover is not None and ta.sum() > 0:
            occluded[k] = float((ta * cover).sum() / ta.sum())
        if plan.gain[k] != 1.0:
            frame = cv2.convertScaleAbs(frame, alpha=float(plan.gain[k]))
        sink(k, frame)

    visible = in_image * (1.0 - occluded)
    gt = _clip_boxes(gt_full, W, H)
    absent = visible < ABSENT_BELOW
    gt[absent] = np.nan
    Hs = np.empty_like(plan.G)
    Hs[0] = np.eye(3)
    for k in range(1, n):
        Hk = plan.G[k] @ np.linalg.inv(plan.G[k - 1])
        Hs[k] = Hk / Hk[2, 2]
    facts = dict(in_image=in_image, distractor_in=distractor_in, contrast=contrast, events=events,
                 gain=plan.gain, gt_full=gt_full, angle=plan.target.angle + _image_yaw(plan.G, plan.target.xy))
    flags = attribute_flags(gt, gt_full, visible, in_image, occluded, Hs, plan.gain, distractor_in,
                            contrast, facts["angle"], W, H, s)
    attrs = frozenset(a for a, f in zip(UAV123_ATTRIBUTES, flags) if f)
    return RenderedSequence(spec, [], gt, Hs, attrs, flags, visible, occluded, plan.G.copy(), facts)


def _accumulate_cover(cover: np.ndarray, tx0: int, ty0: int, x0: int, y0: int, a: np.ndarray) -> None:
    """cover <- 1 - (1 - cover)(1 - a) on the overlap of the target's and an occluder's rects."""
    h, w = cover.shape
    ox0, oy0 = max(tx0, x0), max(ty0, y0)
    ox1, oy1 = min(tx0 + w, x0 + a.shape[1]), min(ty0 + h, y0 + a.shape[0])
    if ox1 <= ox0 or oy1 <= oy0:
        return
    c = cover[oy0 - ty0:oy1 - ty0, ox0 - tx0:ox1 - tx0]
    c[:] = 1.0 - (1.0 - c) * (1.0 - a[oy0 - y0:oy1 - y0, ox0 - x0:ox1 - x0])


def _contrast(frame: np.ndarray, x0: int, y0: int, a: np.ndarray) -> float:
    """Colour distance between the target's pixels and a ring of background around its box."""
    h, w = a.shape
    m = a > 0.5
    if m.sum() < 4:
        return float("nan")
    inner = frame[y0:y0 + h, x0:x0 + w][m].astype(np.float32).mean(0)
    pad = max(2, int(0.5 * max(h, w)))
    X0, Y0 = max(0, x0 - pad), max(0, y0 - pad)
    X1, Y1 = min(frame.shape[1], x0 + w + pad), min(frame.shape[0], y0 + h + pad)
    ring = np.ones((Y1 - Y0, X1 - X0), bool)
    ring[y0 - Y0:y0 - Y0 + h, x0 - X0:x0 - X0 + w] = False
    if ring.sum() < 4:
        return float("nan")
    outer = frame[Y0:Y1, X0:X1][ring].astype(np.float32).mean(0)
    return float(np.linalg.norm(inner - outer))


def _image_yaw(G: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Per frame, the image angle of the ground x axis at ground point ``at[k]`` (so that a
    sprite's ground angle plus this is its angle in the image)."""
    one = np.ones((len(G), 1))
    p = np.einsum("nij,nj->ni", G, np.hstack([at, one]))
    q = np.einsum("nij,nj->ni", G, np.hstack([at + [1.0, 0.0], one]))
    d = q[:, :2] / q[:, 2:] - p[:, :2] / p[:, 2:]
    return np.arctan2(d[:, 1], d[:, 0])


def _clip_boxes(boxes: np.ndarray, W: int, H: int) -> np.ndarray:
    x0 = np.clip(boxes[:, 0], 0, W)
    y0 = np.clip(boxes[:, 1], 0, H)
    x1 = np.clip(boxes[:, 0] + boxes[:, 2], 0, W)
    y1 = np.clip(boxes[:, 1] + boxes[:, 3], 0, H)
    return np.stack([x0, y0, x1 - x0, y1 - y0], axis=1)


def render_sequence(spec: SequenceSpec | int, n_frames: int = 300, width: int = 1280,
                    height: int = 720) -> RenderedSequence:
    """Render a sequence in memory (a spec, or a seed drawn into one with :func:`make_spec`).
    Unpacks as ``frames, groundtruth, homographies, attributes``. Mind the memory: 300 frames of
    1280x720 are 830 MB; use small sizes here, :func:`write_suite` streams to disk."""
    if not isinstance(spec, SequenceSpec):
        spec = make_spec(int(spec), n_frames, width, height)
    frames: list[np.ndarray] = []
    out = render(spec, lambda k, img: frames.append(img))
    return dataclasses.replace(out, frames=frames)
