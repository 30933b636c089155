"""Procedural images for the synthetic UAV generator (:mod:`mata_eval.data.synth`): the textured
ground plane and the sprites (vehicles, persons, tree canopies) that move or stand on it.

Everything is drawn with OpenCV primitives and numpy noise from a seeded generator, so a seed
gives the same pixels on every machine. The ground is structured at several scales (fields,
roads with markings, buildings with shadows, noise octaves) so that sparse optical flow finds
corners everywhere, as on real aerial footage.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# BGR palettes (uint8), loosely after aerial imagery.
_FIELD_COLOURS = np.array([
    (60, 120, 70), (50, 100, 60), (70, 140, 110), (80, 150, 150), (60, 110, 130),
    (90, 160, 170), (40, 90, 70), (100, 130, 120), (70, 120, 150), (55, 135, 95),
], dtype=np.float32)
_ROOF_COLOURS = np.array([
    (60, 60, 150), (70, 80, 170), (150, 150, 150), (110, 110, 120), (80, 90, 100), (170, 170, 180),
], dtype=np.float32)
_VEHICLE_COLOURS = np.array([
    (230, 230, 230), (30, 30, 30), (40, 40, 190), (170, 90, 30), (150, 150, 150), (30, 160, 210),
    (60, 110, 40),
], dtype=np.float32)


def _noise_octaves(size: int, rng: np.random.Generator, cells: tuple[int, ...],
                   amps: tuple[float, ...]) -> np.ndarray:
    """Sum of smooth noise fields, one per cell size (cubic upsampling of a coarse grid)."""
    out = np.zeros((size, size), np.float32)
    for cell, amp in zip(cells, amps):
        n = max(2, size // cell + 2)
        coarse = rng.standard_normal((n, n), dtype=np.float32)
        out += amp * cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
    return out


def ground_texture(size: int, rng: np.random.Generator) -> np.ndarray:
    """A square (size, size, 3) uint8 BGR aerial ground: rotated patchwork of fields, a road
    network with dashed centre lines, buildings with shadows, and noise at four scales.

    The layout is drawn at half resolution and upsampled (4x fewer pixels to shade), then a
    full-resolution grain is added so that the finest scale still has corners for optical flow."""
    half = max(16, size // 2)
    img = _ground_layout(half, rng)
    img = cv2.resize(img, (size, size), interpolation=cv2.INTER_LINEAR)
    grain = rng.integers(0, 17, (size, size), dtype=np.uint8)
    grain = cv2.merge([grain, grain, grain])
    img = cv2.add(img, grain)
    return cv2.subtract(img, (8, 8, 8, 0))


def _ground_layout(size: int, rng: np.random.Generator) -> np.ndarray:
    s = size / 4096.0  # geometric scale relative to a full-size (4096 px) texture
    # Fields: a coarse random label grid, nearest-upsampled (rectangular plots), then rotated.
    plot = max(8, int(220 * s))
    n = size // plot + 3
    labels = rng.integers(0, len(_FIELD_COLOURS), (n, n), dtype=np.uint8)
    big = cv2.resize(labels, (n * plot, n * plot), interpolation=cv2.INTER_NEAREST)
    angle = float(rng.uniform(0, 90))
    c = n * plot / 2.0
    rot = cv2.getRotationMatrix2D((c, c), angle, 1.0)
    rot[:, 2] += size / 2.0 - c
    big = cv2.warpAffine(big, rot, (size, size), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REFLECT)
    img = _FIELD_COLOURS[big]

    # Crop rows inside the fields (sin(ax + by) as two outer products: no per-pixel grid) and
    # multi-scale noise, luminance plus a little chroma.
    period = max(3.0, 14.0 * s)
    th = np.deg2rad(angle)
    r = np.arange(size, dtype=np.float32) * np.float32(2 * np.pi / period)
    ax, by = r * np.float32(np.cos(th)), r * np.float32(np.sin(th))
    lum = np.outer(np.sin(by), np.cos(ax)) + np.outer(np.cos(by), np.sin(ax))
    lum *= 6.0
    lum += _noise_octaves(size, rng, (int(600 * s) + 2, int(120 * s) + 2, int(24 * s) + 2), (14.0, 10.0, 7.0))
    lum += rng.standard_normal((size, size), dtype=np.float32) * 5.0
    img += lum[..., None]
    img[..., 1] += _noise_octaves(size, rng, (int(300 * s) + 2,), (8.0,))
    img = np.clip(img, 0, 255).astype(np.uint8)

    # Roads: long straight and bent polylines, asphalt grey with dashed white centre lines.
    for _ in range(int(rng.integers(4, 8))):
        p0 = rng.uniform(0, size, 2)
        heading = rng.uniform(0, 2 * np.pi)
        pts = [p0]
        for _ in range(4):
            heading += rng.normal(0, 0.35)
            step = rng.uniform(0.3, 0.6) * size
            pts.append(pts[-1] + step * np.array([np.cos(heading), np.sin(heading)]))
        poly = np.array(pts).astype(np.int32)
        width = max(3, int(rng.uniform(40, 70) * s))
        grey = int(rng.integers(70, 110))
        cv2.polylines(img, [poly], False, (grey + 8, grey + 4, grey), width, cv2.LINE_AA)
        # dashed centre line
        dash = max(4, int(40 * s))
        for a, b in zip(poly[:-1], poly[1:]):
            length = float(np.hypot(*(b - a)))
            k = int(length // (2 * dash))
            for i in range(k):
                q0 = a + (b - a) * (2 * i * dash / length)
                q1 = a + (b - a) * ((2 * i + 1) * dash / length)
                cv2.line(img, tuple(int(v) for v in q0), tuple(int(v) for v in q1), (220, 220, 220),
                         max(1, int(4 * s)), cv2.LINE_AA)

    # Buildings: rotated rectangles with a roof ridge and a cast shadow.
    nb = int(rng.integers(60, 110) * (s * s) ** 0.5) + 4
    for _ in range(nb):
        cx, cy = rng.uniform(0, size, 2)
        w, h = rng.uniform(50, 180, 2) * s + 4
        ang = float(rng.uniform(0, 180))
        box = cv2.boxPoints(((cx, cy), (w, h), ang)).astype(np.int32)
        shadow = box + np.array([int(0.25 * w), int(0.2 * h)])
        cv2.fillConvexPoly(img, shadow, (35, 40, 40), cv2.LINE_AA)
        roof = _ROOF_COLOURS[rng.integers(len(_ROOF_COLOURS))] + rng.normal(0, 12, 3)
        cv2.fillConvexPoly(img, box, tuple(float(v) for v in np.clip(roof, 0, 255)), cv2.LINE_AA)
        mid = ((box[0] + box[1]) // 2, (box[2] + box[3]) // 2)
        cv2.line(img, tuple(int(v) for v in mid[0]), tuple(int(v) for v in mid[1]),
                 tuple(float(v) for v in np.clip(roof * 0.7, 0, 255)), max(1, int(3 * s)), cv2.LINE_AA)
    return img


@dataclass(frozen=True, eq=False)
class Sprite:
    """A BGRA image drawn onto the ground plane, and its outline polygon in sprite pixels
    (the silhouette whose projected bounding box is the ground truth). Colours are premultiplied
    by alpha, so bilinear warping does not darken the edges."""

    bgra: np.ndarray            # (h, w, 4) uint8 premultiplied BGR, alpha 0..255
    outline: np.ndarray         # (M, 2) float, sprite pixel coordinates
    pixel_size: float           # ground units per sprite pixel

    @property
    def alpha_mass(self) -> float:
        """Sum of alpha (0..1) over the sprite: its silhouette area in sprite pixels."""
        return float(self.bgra[..., 3].sum()) / 255.0

    @property
    def outline_area(self) -> float:
        return float(abs(cv2.contourArea(self.outline.astype(np.float32))))

    @property
    def size(self) -> tuple[int, int]:
        return self.bgra.shape[1], self.bgra.shape[0]


_SUPERSAMPLE = 2  # sprites are drawn at twice the ground resolution, for clean edges when warped


def vehicle_sprite(length: float, width: float, colour: np.ndarray, rng: np.random.Generator) -> Sprite:
    """Top view of a car (pointing along +x): body, darker windows, roof, a little noise."""
    k = _SUPERSAMPLE
    L, W = max(4, int(round(length * k))), max(3, int(round(width * k)))
    pad = 2
    img = np.zeros((W + 2 * pad, L + 2 * pad, 4), np.float32)
    body = colour.astype(np.float32)
    cham = max(1, int(0.15 * W))
    outline = np.array([[pad + cham, pad], [pad + L - cham, pad], [pad + L, pad + cham],
                        [pad + L, pad + W - cham], [pad + L - cham, pad + W], [pad + cham, pad + W],
                        [pad, pad + W - cham], [pad, pad + cham]], np.float32)
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillPoly(mask, [np.round(outline).astype(np.int32)], 255, cv2.LINE_AA)
    img[..., :3] = body
    win = tuple(float(v) for v in body * 0.35)
    cv2.rectangle(img, (pad + int(0.55 * L), pad + int(0.12 * W)), (pad + int(0.72 * L), pad + int(0.88 * W)),
                  win + (0.0,), -1)
    cv2.rectangle(img, (pad + int(0.12 * L), pad + int(0.15 * W)), (pad + int(0.25 * L), pad + int(0.85 * W)),
                  win + (0.0,), -1)
    roof = tuple(float(v) for v in np.clip(body * 1.1 + 15, 0, 255))
    cv2.rectangle(img, (pad + int(0.28 * L), pad + int(0.18 * W)), (pad + int(0.52 * L), pad + int(0.82 * W)),
                  roof + (0.0,), -1)
    img[..., :3] += rng.normal(0, 6, img.shape[:2])[..., None]
    return _sprite(img, mask, outline, k)


def person_sprite(height: float, colour: np.ndarray, rng: np.random.Generator) -> Sprite:
    """An oblique view of a walking person (head up along -y): head, torso, legs."""
    k = _SUPERSAMPLE
    H = max(6, int(round(height * k)))
    W = max(3, int(round(0.42 * height * k)))
    pad = 2
    img = np.zeros((H + 2 * pad, W + 2 * pad, 4), np.float32)
    cx = pad + W / 2.0
    head_r = 0.11 * H
    outline = []
    for a in np.linspace(np.pi, 2 * np.pi, 7):                 # top of the head
        outline.append((cx + head_r * np.cos(a), pad + head_r + head_r * np.sin(a)))
    outline += [(pad + W, pad + 0.28 * H), (pad + 0.85 * W, pad + 0.62 * H), (pad + 0.75 * W, pad + H),
                (pad + 0.25 * W, pad + H), (pad + 0.15 * W, pad + 0.62 * H), (pad, pad + 0.28 * H)]
    outline = np.array(outline, np.float32)
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillPoly(mask, [np.round(outline).astype(np.int32)], 255, cv2.LINE_AA)
    shirt = colour.astype(np.float32)
    img[..., :3] = shirt
    legs = tuple(float(v) for v in rng.uniform(20, 90, 3))
    img[int(pad + 0.6 * H):, :, :3] = legs
    skin = (110.0, 150.0, 200.0)
    cv2.circle(img, (int(cx), int(pad + 1.1 * head_r)), max(1, int(head_r)), skin + (0.0,), -1)
    img[..., :3] += rng.normal(0, 6, img.shape[:2])[..., None]
    return _sprite(img, mask, outline, k)


def tree_sprite(radius: float, rng: np.random.Generator) -> Sprite:
    """A tree canopy seen from above: a lumpy dark-green blob with leaf noise, opaque."""
    k = _SUPERSAMPLE
    r = max(3.0, radius * k)
    n = 24
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rad = r * (1 + 0.12 * np.sin(3 * ang + rng.uniform(0, 6)) + rng.uniform(-0.06, 0.06, n))
    side = int(np.ceil(2 * rad.max())) + 4
    c = side / 2.0
    outline = np.stack([c + rad * np.cos(ang), c + rad * np.sin(ang)], axis=1).astype(np.float32)
    img = np.zeros((side, side, 4), np.float32)
    mask = np.zeros((side, side), np.uint8)
    cv2.fillPoly(mask, [np.round(outline).astype(np.int32)], 255, cv2.LINE_AA)
    green = np.array((30, 85, 40), np.float32) + rng.normal(0, 8, 3)
    img[..., :3] = green
    leaves = cv2.GaussianBlur(rng.standard_normal((side, side)).astype(np.float32), (0, 0), max(0.8, r / 12))
    img[..., :3] += (leaves / (leaves.std() + 1e-6) * 14)[..., None]
    return _sprite(img, mask, outline, k)


def _sprite(img: np.ndarray, mask: np.ndarray, outline: np.ndarray, k: int) -> Sprite:
    a = mask.astype(np.float32) / 255.0
    img[..., :3] = np.clip(img[..., :3], 0, 255) * a[..., None]
    img[..., 3] = mask
    return Sprite(np.clip(np.round(img), 0, 255).astype(np.uint8), outline, 1.0 / k)


def vehicle_colour(rng: np.random.Generator) -> np.ndarray:
    return np.clip(_VEHICLE_COLOURS[rng.integers(len(_VEHICLE_COLOURS))] + rng.normal(0, 10, 3), 0, 255)
