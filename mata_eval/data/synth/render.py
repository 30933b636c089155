"""Synthetic UAV sequences with exact ego-motion (`mata-eval synth`).

A textured ground plane (:mod:`mata_eval.data.synth.texture`) is seen by a pinhole camera that
follows a target the way a UAV operator would: smooth pursuit with lag, yaw, tilt, zoom and roll
changes, sudden manoeuvres (quick pans, yaw jerks, zoom jumps) and, on request, out-of-view spells
where the camera looks away. Vehicle- or person-like sprites move on the ground with constant
velocity, turns and accelerations; distractors of the same look move near the target; tree
canopies occlude it. Every frame is ``cv2.warpPerspective`` of the pre-rendered ground with the
plane-to-image homography ``G_k``, so the true inter-frame homography ``H_k = G_k G_{k-1}^-1``
(paper section 2.2's block B target) is known exactly.

In memory: :func:`render_sequence`. On disk, in the UAV123 layout (frames, ground truth,
attribute flags, ``configSeqs.m``, true homographies): :func:`write_suite`.
Ground truth follows UAV123: the target's axis-aligned box clipped to the image, ``NaN`` rows when
it is fully out of view or fully occluded. Attribute flags are computed from what was generated
(see ``docs/decisions/data.md`` for the thresholds).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Literal

import cv2
import numpy as np

from . import texture as tex

#: UAV123 attribute flag order (``anno/UAV123/att/<seq>.txt``).
UAV123_ATTRIBUTES = ("SV", "ARC", "LR", "FM", "FOC", "POC", "OV", "BC", "IV", "VC", "CM", "SOB")

#: Scenario cycle of the default suite: every suite covers each kind of difficulty.
SCENARIOS = ("cruise", "manoeuvre", "outofview", "occlusion", "crowd")

_REF_WIDTH = 1280.0  # geometry, speeds and attribute thresholds scale with width / 1280
GENERATOR_VERSION = 3  # bump when the pixels a seed gives change (cache key of the suite)


@dataclass(frozen=True)
class SequenceSpec:
    """Everything that determines a synthetic sequence; the same spec gives the same pixels."""

    name: str
    seed: int
    n_frames: int = 300
    width: int = 1280
    height: int = 720
    fps: float = 30.0
    texture_seed: int = 0
    target: Literal["vehicle", "person"] = "vehicle"
    n_distractors: int = 0
    manoeuvres: int = 0          # sudden pans / yaw jerks / zoom jumps
    out_of_view: bool = False    # the camera looks away until the target has left the image
    occlusion: Literal["none", "partial", "full"] = "none"  # a tree canopy on the target's path
    illumination: bool = False   # a cloud shadow darkens the scene for a while
    camouflage: bool = False     # the target takes the colour of the ground where it starts
    draw_target: bool = True     # False renders the same scene without the target (tests)

    def __post_init__(self) -> None:
        if self.n_frames < 2:
            raise ValueError(f"SequenceSpec {self.name!r}: n_frames must be >= 2, got {self.n_frames}")
        if self.width < 32 or self.height < 24:
            raise ValueError(f"SequenceSpec {self.name!r}: image size must be at least 32x24, "
                             f"got {self.width}x{self.height}")


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


# --- specs ------------------------------------------------------------------------------------

def _derive(*key: int) -> int:
    return int(np.random.SeedSequence([int(k) & 0xFFFFFFFF for k in key]).generate_state(1)[0])


def make_spec(seed: int, n_frames: int = 300, width: int = 1280, height: int = 720, *,
              name: str | None = None, scenario: str | None = None, texture_seed: int | None = None,
              fps: float = 30.0) -> SequenceSpec:
    """A random sequence spec for ``seed``; ``scenario`` (one of :data:`SCENARIOS`) picks which
    difficulties it stages, the rest is drawn from the seed."""
    rng = np.random.default_rng(_derive(seed, 1))
    scenario = scenario if scenario is not None else SCENARIOS[int(rng.integers(len(SCENARIOS)))]
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; expected one of {', '.join(SCENARIOS)}")
    target = "person" if (scenario == "crowd" or rng.random() < 0.3) else "vehicle"
    spec = dict(
        target=target,
        n_distractors=int(rng.integers(2, 4)) if scenario == "crowd" else int(rng.random() < 0.3),
        manoeuvres=int(rng.integers(1, 3)) if scenario == "manoeuvre" else int(rng.random() < 0.2),
        out_of_view=scenario == "outofview",
        occlusion=("full" if rng.random() < 0.6 else "partial") if scenario == "occlusion" else "none",
        illumination=scenario == "crowd" or bool(rng.random() < 0.15),
    )
    spec["camouflage"] = scenario in ("cruise", "crowd") and bool(rng.random() < 0.4)
    return SequenceSpec(name=name or f"syn{seed % 100000:05d}_{scenario}", seed=int(seed), n_frames=n_frames,
                        width=width, height=height, fps=fps,
                        texture_seed=int(texture_seed if texture_seed is not None else _derive(seed, 2)), **spec)


def suite_specs(n_sequences: int = 20, n_frames: int = 300, width: int = 1280, height: int = 720,
                seed: int = 0, n_textures: int = 4) -> list[SequenceSpec]:
    """The default suite: sequence ``i`` is named ``syn<i+1>_<scenario>``, stages the scenario
    ``SCENARIOS[i % 5]`` and depends only on ``(seed, i)`` (not on ``n_sequences``); ground
    textures are shared by groups of sequences (``n_textures`` different grounds)."""
    if n_sequences < 1:
        raise ValueError(f"n_sequences must be >= 1, got {n_sequences}")
    specs = []
    for i in range(n_sequences):
        sp = make_spec(_derive(seed, 100, i), n_frames, width, height,
                       name=f"syn{i + 1:03d}_{SCENARIOS[i % len(SCENARIOS)]}",
                       scenario=SCENARIOS[i % len(SCENARIOS)],
                       texture_seed=_derive(seed, 200, i % max(1, n_textures)))
        if sp.occlusion != "none":  # alternate full and partial occlusions through the suite
            sp = dataclasses.replace(sp, occlusion="full" if (i // len(SCENARIOS)) % 2 == 0 else "partial")
        specs.append(sp)
    return specs


# --- motion -----------------------------------------------------------------------------------

def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _smooth_noise(rng: np.random.Generator, n: int, scale: float, corr: float) -> np.ndarray:
    """Gaussian-smoothed white noise with std ``scale`` and correlation length ``corr`` frames."""
    w = rng.standard_normal(n + 6 * int(corr) + 2)
    k = np.exp(-0.5 * (np.arange(-3 * int(corr) - 1, 3 * int(corr) + 2) / max(corr, 1e-3)) ** 2)
    sm = np.convolve(w, k / np.sqrt((k ** 2).sum()), mode="valid")[:n]
    return scale * sm


def _piecewise(rng: np.random.Generator, n: int, lo: float, hi: float, seg: tuple[int, int]) -> np.ndarray:
    """Piecewise-constant random values in [lo, hi], segment lengths drawn in ``seg`` frames."""
    out = np.empty(n)
    k = 0
    while k < n:
        m = int(rng.integers(seg[0], seg[1] + 1))
        out[k:k + m] = rng.uniform(lo, hi)
        k += m
    return out


def _kinematics(rng: np.random.Generator, n: int, speed: float, turn: float, accel: float,
                heading0: float) -> tuple[np.ndarray, np.ndarray]:
    """Ground positions (n, 2) relative to the start and headings (n,) of a mover with constant
    velocity spells, turns (piecewise-constant yaw rate) and accelerations."""
    seg = (max(3, n // 10), max(4, n // 3))
    omega = _piecewise(rng, n, -turn, turn, seg)
    omega[: max(1, n // 10)] = 0.0
    acc = _piecewise(rng, n, -accel, accel, seg)
    heading = heading0 + np.cumsum(omega)
    v = np.clip(speed + np.cumsum(acc), 0.3 * speed, 1.8 * speed)
    step = np.stack([np.cos(heading), np.sin(heading)], axis=1) * v[:, None]
    step[0] = 0.0
    return np.cumsum(step, axis=0), heading


@dataclass(frozen=True, eq=False)
class _Placed:
    sprite: tex.Sprite
    xy: np.ndarray        # (n, 2) ground positions, or (2,) for static sprites
    angle: np.ndarray     # (n,) rotation of the sprite's x axis on the ground


@dataclass(frozen=True, eq=False)
class _Tree:
    """A tree canopy at a fixed ground position; its sprite is drawn on first sight."""
    xy: np.ndarray
    radius: float
    seed: int

    def placed(self) -> _Placed:
        return _Placed(tex.tree_sprite(self.radius, np.random.default_rng(self.seed)), self.xy, np.zeros(1))


@dataclass(frozen=True, eq=False)
class _Plan:
    G: np.ndarray               # (n, 3, 3) ground -> image
    gain: np.ndarray            # (n,) illumination gain
    target: _Placed
    distractors: list[_Placed]
    trees: list[_Tree]
    texture_size: int


def _camera(L: np.ndarray, Z: float, yaw: float, tilt: float, roll: float, f: float,
            W: int, H: int) -> np.ndarray:
    """Ground-plane (z = 0, texture pixels) to image homography of a pinhole camera above the
    plane looking at ``L`` with off-nadir ``tilt`` along the image-up direction ``yaw``."""
    h = np.array([np.sin(yaw), -np.cos(yaw), 0.0])          # image-up direction on the ground
    C = np.array([L[0], L[1], 0.0]) - Z * np.tan(tilt) * h - np.array([0.0, 0.0, Z])
    z = np.array([L[0], L[1], 0.0]) - C
    z /= np.linalg.norm(z)
    up = h - (h @ z) * z
    y = -up / np.linalg.norm(up)
    x = np.cross(y, z)
    cr, sr = np.cos(roll), np.sin(roll)
    x, y = cr * x + sr * y, -sr * x + cr * y
    R = np.stack([x, y, z])
    t = -R @ C
    K = np.array([[f, 0, W / 2.0], [0, f, H / 2.0], [0, 0, 1.0]])
    G = K @ np.column_stack([R[:, 0], R[:, 1], t])
    return G / G[2, 2]


def _texture_size(width: int) -> int:
    """Side of the square ground texture: 4096 px at 1280 px wide frames."""
    return max(256, int(round(4096 * width / _REF_WIDTH)))


def _plan(spec: SequenceSpec, ground: np.ndarray) -> tuple[_Plan, list[dict]]:
    rng = np.random.default_rng(_derive(spec.seed, 3))
    n, W, H = spec.n_frames, spec.width, spec.height
    s = W / _REF_WIDTH
    T = _texture_size(W)
    centre = np.array([T / 2.0, T / 2.0])
    srng = np.random.default_rng(_derive(spec.seed, 4))

    # Target.
    if spec.target == "vehicle":
        length = rng.uniform(36, 60) * s
        colour = tex.vehicle_colour(rng)
        make = lambda r: tex.vehicle_sprite(length * r.uniform(0.92, 1.08), 0.46 * length, colour + r.normal(0, 8, 3), r)  # noqa: E731
        speed, turn, accel = rng.uniform(1.5, 4.0) * s, 0.025, 0.04 * s
    else:
        length = rng.uniform(34, 52) * s
        colour = np.clip(rng.uniform(30, 230, 3), 0, 255)
        make = lambda r: tex.person_sprite(length * r.uniform(0.92, 1.08), np.clip(colour + r.normal(0, 8, 3), 0, 255), r)  # noqa: E731
        speed, turn, accel = rng.uniform(0.5, 1.3) * s, 0.04, 0.015 * s
    if spec.occlusion != "none":  # fast enough to start clear of the canopy and reach it
        speed = max(speed, 4.5 * length / (0.4 * n))
    rel, heading = _kinematics(rng, n, speed, turn, accel, rng.uniform(0, 2 * np.pi))
    shift = centre - (rel.min(0) + rel.max(0)) / 2.0
    P = rel + shift
    if spec.camouflage:  # background clutter: the median ground colour around the start
        r0 = int(max(4, 3 * length))
        x, y = (int(v) for v in np.clip(P[0], r0, T - r0 - 1))
        patch = ground[y - r0:y + r0, x - r0:x + r0].reshape(-1, 3)
        colour = np.clip(np.median(patch, axis=0) + np.random.default_rng(_derive(spec.seed, 6)).normal(0, 6, 3), 0, 255)

    # Camera: pursuit with lag, slow yaw/tilt/zoom/roll drift, shake, manoeuvres, OV spell.
    Z = 1000.0 * s
    yaw = rng.uniform(0, 2 * np.pi) + np.cumsum(_smooth_noise(rng, n, 0.004, 20))
    tilt = np.clip(np.deg2rad(rng.uniform(0, 18)) + _smooth_noise(rng, n, np.deg2rad(4), 40), 0, np.deg2rad(28))
    logzoom = np.log(rng.uniform(0.95, 1.35)) + np.cumsum(_smooth_noise(rng, n, 0.004, 30))
    roll = _smooth_noise(rng, n, np.deg2rad(1.0), 25)
    push = np.zeros((n, 2))
    events: list[dict] = []
    for _ in range(spec.manoeuvres):
        k0 = int(rng.integers(max(1, int(0.15 * n)), max(2, int(0.85 * n))))
        d = int(rng.integers(3, 7))
        kind = ["pan", "yaw", "zoom"][int(rng.integers(3))] if n > 20 else "pan"
        sl = slice(k0, min(n, k0 + d))
        if kind == "pan":
            a = rng.uniform(0.15, 0.3) * W * rng.choice([-1, 1], 2) / math.sqrt(2)
            push[sl] += a / d
        elif kind == "yaw":
            yaw[k0:] += np.deg2rad(rng.uniform(15, 35)) * rng.choice([-1, 1]) * _smoothstep((np.arange(k0, n) - k0 + 1) / d)
        else:
            logzoom[k0:] += rng.uniform(0.2, 0.35) * rng.choice([-1, 1]) * _smoothstep((np.arange(k0, n) - k0 + 1) / d)
        events.append({"kind": kind, "frame": k0, "frames": d})
    logzoom = np.clip(logzoom, np.log(0.75), np.log(1.9))
    zoom = np.exp(logzoom)
    shake = np.stack([_smooth_noise(rng, n, 0.6 * s, 3), _smooth_noise(rng, n, 0.6 * s, 3)], axis=1)
    alpha = 0.08
    L = np.empty((n, 2))
    L[0] = P[0]
    for k in range(1, n):
        L[k] = L[k - 1] + alpha * (P[k] - L[k - 1]) + push[k]
    L += shake
    if spec.out_of_view:
        rise = int(np.clip(round(0.05 * n), 2, 15))
        hold = int(np.clip(round(0.12 * n), 2, 40))
        k0 = int(rng.integers(max(1, int(0.25 * n)), max(2, n - 2 * rise - hold)))
        k = np.arange(n)
        bump = _smoothstep((k - k0) / rise) - _smoothstep((k - k0 - rise - hold) / rise)
        direction = rng.uniform(0, 2 * np.pi)
        D = 1.4 * (0.5 * math.hypot(W, H) + 2 * length) / zoom.min()
        L += bump[:, None] * D * np.array([np.cos(direction), np.sin(direction)])
        events.append({"kind": "out_of_view", "frame": k0, "frames": 2 * rise + hold})
    G = np.stack([_camera(L[k], Z, yaw[k], tilt[k], roll[k], Z * zoom[k], W, H) for k in range(n)])

    gain = np.ones(n)
    if spec.illumination:
        k0 = int(rng.integers(int(0.2 * n), max(int(0.2 * n) + 1, int(0.6 * n))))
        d = int(np.clip(0.15 * n, 2, 40))
        k = np.arange(n)
        gain -= rng.uniform(0.3, 0.45) * (_smoothstep((k - k0) / d) - _smoothstep((k - k0 - 2 * d) / d))

    target_angle = heading if spec.target == "vehicle" else yaw.copy()
    target = _Placed(make(srng), P, target_angle)

    distractors = []
    for _ in range(spec.n_distractors):
        r = rng.uniform(3, 7) * length
        a = rng.uniform(0, 2 * np.pi)
        drel, dhead = _kinematics(rng, n, speed * rng.uniform(0.8, 1.2), turn, accel, heading[0] + rng.normal(0, 0.3))
        dxy = drel + P[0] + r * np.array([np.cos(a), np.sin(a)])
        distractors.append(_Placed(make(srng), dxy, dhead if spec.target == "vehicle" else yaw.copy()))

    trees = []
    if spec.occlusion != "none":
        radius = rng.uniform(1.0, 1.4) * length if spec.occlusion == "full" else rng.uniform(0.5, 0.8) * length
        k_occ = int(rng.integers(max(1, int(0.35 * n)), max(2, int(0.75 * n))))
        while k_occ < n - 1 and np.linalg.norm(P[k_occ] - P[0]) < 2.2 * radius + 1.5 * length:
            k_occ += 1  # the target must start clear of the canopy (tracker initialisation)
        side = rng.choice([-1, 1]) * (0.0 if spec.occlusion == "full" else rng.uniform(0.7, 1.1) * radius)
        normal = np.array([-np.sin(heading[k_occ]), np.cos(heading[k_occ])])
        if np.linalg.norm(P[k_occ] - P[0]) >= 2.2 * radius + 1.5 * length:
            trees.append(_Tree(P[k_occ] + side * normal, float(radius), _derive(spec.seed, 5, 0)))
            events.append({"kind": "tree", "frame": k_occ, "radius": float(radius)})
    # Scenery trees, kept away from the target's path (only the staged tree may occlude it).
    cand = rng.uniform(0, T, (int(60 * (T / 4096) ** 2) + 4, 2))
    radii = rng.uniform(0.6, 1.6, len(cand)) * 40 * s
    dist = np.min(np.linalg.norm(cand[:, None, :] - P[None, ::max(1, n // 100), :], axis=2), axis=1)
    for i, (c, r) in enumerate(zip(cand[dist > radii + 2.5 * length], radii[dist > radii + 2.5 * length])):
        trees.append(_Tree(c, float(r), _derive(spec.seed, 5, i + 1)))
    return _Plan(G, gain, target, distractors, trees, T), events


# --- rendering --------------------------------------------------------------------------------

def _sprite_to_ground(placed: _Placed, k: int) -> np.ndarray:
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


def _projected_outline(placed: _Placed, G: np.ndarray, k: int) -> np.ndarray:
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


def _render(spec: SequenceSpec, sink: Callable[[int, np.ndarray], None]) -> RenderedSequence:
    ground = ground_texture(spec.texture_seed, _texture_size(spec.width))
    plan, events = _plan(spec, ground)
    n, W, H = spec.n_frames, spec.width, spec.height
    s = W / _REF_WIDTH
    gt_full = np.full((n, 4), np.nan)       # unclipped box of the projected silhouette
    in_image = np.zeros(n)                  # fraction of the silhouette area inside the image
    occluded = np.zeros(n)                  # fraction of the in-image part covered by trees
    distractor_in = np.zeros(n)             # best in-image fraction of a distractor
    contrast = np.full(n, np.nan)           # target vs surrounding colour distance (sampled)
    tree_centres = np.array([t.xy for t in plan.trees]).reshape(-1, 2)
    tree_reach = np.array([1.4 * t.radius + 4 for t in plan.trees])
    tree_sprites: dict[int, _Placed] = {}

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


#: a target with less than this fraction of its area visible (in the image and not occluded) is
#: "fully out of view / fully occluded": its ground-truth row is NaN, as in UAV123.
ABSENT_BELOW = 0.05


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


def attribute_flags(gt: np.ndarray, gt_full: np.ndarray, visible: np.ndarray, in_image: np.ndarray,
                    occluded: np.ndarray, homographies: np.ndarray, gain: np.ndarray,
                    distractor_in: np.ndarray, contrast: np.ndarray, angle: np.ndarray,
                    W: int, H: int, s: float = 1.0) -> tuple[int, ...]:
    """The 12 UAV123 flags (order :data:`UAV123_ATTRIBUTES`) from generated facts, with the
    UAV123 paper's definitions; pixel thresholds scale with ``s = width / 1280``."""
    ok = np.all(np.isfinite(gt), axis=1)
    full = gt_full[ok]
    area = full[:, 2] * full[:, 3]
    aspect = full[:, 2] / np.maximum(full[:, 3], 1e-9)
    a0, r0 = area[0], aspect[0]
    sv = bool(np.any((area / a0 < 0.5) | (area / a0 > 2.0)))
    arc = bool(np.any((aspect / r0 < 0.5) | (aspect / r0 > 2.0)))
    lr = bool(np.any(area < 400 * s * s))
    c = gt[:, :2] + gt[:, 2:] / 2
    step = np.linalg.norm(np.diff(c, axis=0), axis=1)
    fm = bool(np.any(step[np.isfinite(step)] > 20 * s))
    foc = bool(np.any((occluded >= 0.95) & (in_image > 0.05)))
    poc = bool(np.any((occluded >= 0.1) & (occluded < 0.95) & (in_image > 0.05)))
    ov = bool(np.any(in_image < 0.95))
    sampled = contrast[np.isfinite(contrast)]
    bc = bool(np.mean(sampled < 40.0) > 0.3) if len(sampled) else False
    iv = bool(gain.max() / max(gain.min(), 1e-9) > 1.3)
    rel = np.unwrap(angle[ok]) if ok.any() else np.zeros(1)
    vc = bool(np.abs(rel - rel[0]).max() > np.deg2rad(60))
    # CM: an abrupt change of the image motion (a jerk of more than 6 px/frame at the image
    # centre or a corner between consecutive inter-frame homographies).
    pts = np.array([[W / 2, H / 2, 1], [0, 0, 1], [W, 0, 1], [0, H, 1], [W, H, 1]], float)
    moved = np.einsum("nij,pj->npi", homographies, pts)
    disp = moved[..., :2] / moved[..., 2:] - pts[None, :, :2]
    jerk = np.linalg.norm(np.diff(disp[1:], axis=0), axis=2) if len(disp) > 2 else np.zeros((1, 5))
    cm = bool(np.any(jerk > 6 * s))
    sob = bool(np.any((distractor_in >= 0.5) & (visible >= ABSENT_BELOW)))
    return tuple(int(v) for v in (sv, arc, lr, fm, foc, poc, ov, bc, iv, vc, cm, sob))


def render_sequence(spec: SequenceSpec | int, n_frames: int = 300, width: int = 1280,
                    height: int = 720) -> RenderedSequence:
    """Render a sequence in memory (a spec, or a seed drawn into one with :func:`make_spec`).
    Unpacks as ``frames, groundtruth, homographies, attributes``. Mind the memory: 300 frames of
    1280x720 are 830 MB; use small sizes here, :func:`write_suite` streams to disk."""
    if not isinstance(spec, SequenceSpec):
        spec = make_spec(int(spec), n_frames, width, height)
    frames: list[np.ndarray] = []
    out = _render(spec, lambda k, img: frames.append(img))
    return dataclasses.replace(out, frames=frames)


# --- UAV123 layout on disk ----------------------------------------------------------------------

def _fmt_box(b: np.ndarray) -> str:
    if not np.all(np.isfinite(b)):
        return "NaN,NaN,NaN,NaN"
    return ",".join(f"{v:.2f}".rstrip("0").rstrip(".") for v in b)


def write_annotations(root: Path, name: str, r: RenderedSequence) -> None:
    """Ground truth, attribute flags and true homographies of one sequence (UAV123 layout)."""
    anno = root / "anno" / "UAV123"
    (anno / "att").mkdir(parents=True, exist_ok=True)
    (anno / "homography").mkdir(parents=True, exist_ok=True)
    (anno / f"{name}.txt").write_text("\n".join(_fmt_box(b) for b in r.groundtruth) + "\n")
    (anno / "att" / f"{name}.txt").write_text(",".join(str(f) for f in r.flags) + "\n")
    np.savetxt(anno / "homography" / f"{name}.txt", r.homographies.reshape(-1, 9), fmt="%.10g", delimiter=",")


def write_config_seqs(root: Path, names_and_lengths: list[tuple[str, int]]) -> None:
    """``anno/UAV123/configSeqs.m`` in the benchmark kit's syntax, one struct per sequence."""
    rows = [f"struct('name','{n}','path','D:\\data_seq\\UAV123\\{n}\\','startFrame',1,'endFrame',{m},"
            f"'nz',6,'ext','jpg','init_rect', [0,0,0,0])" for n, m in names_and_lengths]
    text = ("function seqs=configSeqs\n\n"
            "% synthetic UAV sequences written by mata-eval synth\n"
            "seqUAV123={" + ",...\n    ".join(rows) + "};\n\n"
            "seqs = seqUAV123;\n")
    path = root / "anno" / "UAV123" / "configSeqs.m"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def load_true_homographies(root: str | Path, seq: str) -> np.ndarray:
    """The true inter-frame homographies of a synthetic sequence, (N, 3, 3), ``H[k]`` mapping
    frame k-1 to frame k (``H[0]`` = identity)."""
    path = Path(root) / "anno" / "UAV123" / "homography" / f"{seq}.txt"
    if not path.is_file():
        raise FileNotFoundError(f"true homographies not found: {path} (written by `mata-eval synth`)")
    try:
        a = np.loadtxt(path, delimiter=",", ndmin=2)
    except ValueError as e:
        raise ValueError(f"{path}: expected one row of 9 comma-separated numbers per frame ({e})") from None
    if a.shape[1] != 9:
        raise ValueError(f"{path}: expected 9 numbers per row (row-major 3x3), got {a.shape[1]}")
    return a.reshape(-1, 3, 3)


def _write_frames(args: tuple[SequenceSpec, str, int]) -> RenderedSequence:
    spec, folder, quality = args
    cv2.setNumThreads(1)
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]

    def sink(k: int, img: np.ndarray) -> None:
        if not cv2.imwrite(str(out / f"{k + 1:06d}.jpg"), img, params):
            raise OSError(f"cannot write frame {out / f'{k + 1:06d}.jpg'}")

    return _render(spec, sink)


SUITE_MARKER = "synth.json"


def write_suite(root: str | Path, n_sequences: int = 20, n_frames: int = 300, width: int = 1280,
                height: int = 720, seed: int = 0, *, jobs: int = 2, quality: int = 90,
                specs: list[SequenceSpec] | None = None, progress: bool = False,
                overwrite: bool = False) -> list[str]:
    """Generate a suite into ``root`` in the UAV123 layout, atomically: everything is written
    into a temporary sibling folder that is renamed to ``root`` when complete (``synth.json``,
    the generation parameters, inside). A crash leaves no half suite at ``root``. Returns the
    sequence names. Raises FileExistsError when ``root`` already holds something (a suite, unless
    ``overwrite``; anything else, always), also when another process completed it meanwhile."""
    root = Path(root)
    suite = None
    if specs is None:
        specs = suite_specs(n_sequences, n_frames, width, height, seed)
        suite = {"n_sequences": n_sequences, "n_frames": n_frames, "width": width, "height": height,
                 "seed": seed}
    names = [sp.name for sp in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"sequence names must be unique, got {names}")
    if (root / SUITE_MARKER).exists() and not overwrite:
        raise FileExistsError(f"{root} already holds a synthetic suite ({SUITE_MARKER}); "
                              "choose another folder or overwrite it (--force)")
    if root.exists() and any(root.iterdir()) and not (root / SUITE_MARKER).exists():
        raise FileExistsError(f"{root} exists and is not empty (and is not a synthetic suite); refusing to replace it")
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = root.parent / f".{root.name}.tmp-{os.getpid()}-{time.time_ns()}"
    tmp.mkdir()
    try:
        tasks = [(sp, str(tmp / "data_seq" / "UAV123" / sp.name), quality) for sp in specs]
        results = _map(_write_frames, tasks, jobs, progress)
        for sp, r in zip(specs, results):
            write_annotations(tmp, sp.name, r)
        write_config_seqs(tmp, [(sp.name, sp.n_frames) for sp in specs])
        (tmp / SUITE_MARKER).write_text(json.dumps({
            "generator_version": GENERATOR_VERSION,
            "suite": suite,
            "sequences": [dataclasses.asdict(sp) for sp in specs],
            "attributes": {sp.name: sorted(r.attributes) for sp, r in zip(specs, results)},
        }, indent=1))
        if root.exists():
            if (root / SUITE_MARKER).exists() and not overwrite:
                raise FileExistsError(f"{root}: another process completed a suite meanwhile")
            if (root / SUITE_MARKER).exists() or not any(root.iterdir()):
                shutil.rmtree(root)
        try:
            os.replace(tmp, root)
        except OSError:
            raise FileExistsError(f"{root}: appeared while generating (another process?)") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return names


def read_suite_info(root: str | Path) -> dict | None:
    """The generation parameters of a complete suite at ``root`` (``synth.json``), or None."""
    path = Path(root) / SUITE_MARKER
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e.msg} at line {e.lineno}); delete the folder to regenerate") from None


def _write_group(tasks: list) -> list[RenderedSequence]:
    return [_write_frames(t) for t in tasks]


def _map(fn, tasks: list, jobs: int, progress: bool) -> list:
    """Run tasks in a process pool of ``jobs`` (spawned workers), results in task order. Tasks
    sharing a ground texture go to the same worker, which generates that ground once."""
    groups: dict[int, list[int]] = {}
    for i, t in enumerate(tasks):
        groups.setdefault(t[0].texture_seed, []).append(i)
    out: list = [None] * len(tasks)
    import multiprocessing as mp

    if mp.current_process().daemon:  # a daemonic pool worker may not start processes
        jobs = 1
    if jobs <= 1 or len(groups) == 1:
        for idx in groups.values():
            for i in idx:
                out[i] = fn(tasks[i])
                if progress:
                    print(f"  {tasks[i][0].name}", flush=True)
        return out
    from concurrent.futures import ProcessPoolExecutor

    runner = _write_group if fn is _write_frames else functools.partial(_apply_all, fn)
    with ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn")) as ex:
        futures = [(idx, ex.submit(runner, [tasks[i] for i in idx])) for idx in groups.values()]
        for idx, fut in futures:
            for i, r in zip(idx, fut.result()):
                out[i] = r
                if progress:
                    print(f"  {tasks[i][0].name}", flush=True)
    return out


def _apply_all(fn, tasks: list) -> list:
    return [fn(t) for t in tasks]


# --- CLI ----------------------------------------------------------------------------------------

def add_cli(subparsers) -> None:
    p = subparsers.add_parser("synth", help="generate synthetic UAV sequences (UAV123 layout, true homographies)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("out", help="dataset root to create (data_seq/UAV123, anno/UAV123 inside)")
    p.add_argument("--n-sequences", type=int, default=20, help="number of sequences (default 20)")
    p.add_argument("--n-frames", type=int, default=300, help="frames per sequence (default 300, 30 fps)")
    p.add_argument("--width", type=int, default=1280, help="frame width (default 1280)")
    p.add_argument("--height", type=int, default=720, help="frame height (default 720)")
    p.add_argument("--seed", type=int, default=0, help="suite seed (default 0)")
    p.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    p.add_argument("--quality", type=int, default=90, help="JPEG quality (default 90)")
    p.add_argument("--force", action="store_true", help="replace an existing suite in OUT")
    p.set_defaults(func=_cmd_synth)


def _cmd_synth(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    try:
        names = write_suite(args.out, args.n_sequences, args.n_frames, args.width, args.height, args.seed,
                            jobs=args.jobs, quality=args.quality, progress=True, overwrite=args.force)
    except (FileExistsError, ValueError) as e:
        print(f"mata-eval synth: {e}")
        return 2
    print(f"wrote {len(names)} sequences to {args.out} in {time.perf_counter() - t0:.1f} s")
    return 0
