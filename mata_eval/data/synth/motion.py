"""How the scene moves: the target's and distractors' kinematics on the ground and the camera's
pursuit (lag, yaw, tilt, zoom, roll, shake, manoeuvres, out-of-view spells), as the per-frame
ground-to-image homographies ``G_k`` of a :class:`Plan` (paper section 2.2: the true inter-frame
homography is ``H_k = G_k G_{k-1}^-1``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import texture as tex
from .spec import REF_WIDTH, SequenceSpec, derive_seed


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
class Placed:
    sprite: tex.Sprite
    xy: np.ndarray        # (n, 2) ground positions, or (2,) for static sprites
    angle: np.ndarray     # (n,) rotation of the sprite's x axis on the ground


@dataclass(frozen=True, eq=False)
class Tree:
    """A tree canopy at a fixed ground position; its sprite is drawn on first sight."""
    xy: np.ndarray
    radius: float
    seed: int

    def placed(self) -> Placed:
        return Placed(tex.tree_sprite(self.radius, np.random.default_rng(self.seed)), self.xy, np.zeros(1))


@dataclass(frozen=True, eq=False)
class Plan:
    G: np.ndarray               # (n, 3, 3) ground -> image
    gain: np.ndarray            # (n,) illumination gain
    target: Placed
    distractors: list[Placed]
    trees: list[Tree]
    texture_size: int


def camera(L: np.ndarray, Z: float, yaw: float, tilt: float, roll: float, f: float,
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


def texture_size(width: int) -> int:
    """Side of the square ground texture: 4096 px at 1280 px wide frames."""
    return max(256, int(round(4096 * width / REF_WIDTH)))


def plan_sequence(spec: SequenceSpec, ground: np.ndarray) -> tuple[Plan, list[dict]]:
    rng = np.random.default_rng(derive_seed(spec.seed, 3))
    n, W, H = spec.n_frames, spec.width, spec.height
    s = W / REF_WIDTH
    T = texture_size(W)
    centre = np.array([T / 2.0, T / 2.0])
    srng = np.random.default_rng(derive_seed(spec.seed, 4))

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
        colour = np.clip(np.median(patch, axis=0) + np.random.default_rng(derive_seed(spec.seed, 6)).normal(0, 6, 3), 0, 255)

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
    G = np.stack([camera(L[k], Z, yaw[k], tilt[k], roll[k], Z * zoom[k], W, H) for k in range(n)])

    gain = np.ones(n)
    if spec.illumination:
        k0 = int(rng.integers(int(0.2 * n), max(int(0.2 * n) + 1, int(0.6 * n))))
        d = int(np.clip(0.15 * n, 2, 40))
        k = np.arange(n)
        gain -= rng.uniform(0.3, 0.45) * (_smoothstep((k - k0) / d) - _smoothstep((k - k0 - 2 * d) / d))

    target_angle = heading if spec.target == "vehicle" else yaw.copy()
    target = Placed(make(srng), P, target_angle)

    distractors = []
    for _ in range(spec.n_distractors):
        r = rng.uniform(3, 7) * length
        a = rng.uniform(0, 2 * np.pi)
        drel, dhead = _kinematics(rng, n, speed * rng.uniform(0.8, 1.2), turn, accel, heading[0] + rng.normal(0, 0.3))
        dxy = drel + P[0] + r * np.array([np.cos(a), np.sin(a)])
        distractors.append(Placed(make(srng), dxy, dhead if spec.target == "vehicle" else yaw.copy()))

    trees = []
    if spec.occlusion != "none":
        radius = rng.uniform(1.0, 1.4) * length if spec.occlusion == "full" else rng.uniform(0.5, 0.8) * length
        k_occ = int(rng.integers(max(1, int(0.35 * n)), max(2, int(0.75 * n))))
        while k_occ < n - 1 and np.linalg.norm(P[k_occ] - P[0]) < 2.2 * radius + 1.5 * length:
            k_occ += 1  # the target must start clear of the canopy (tracker initialisation)
        side = rng.choice([-1, 1]) * (0.0 if spec.occlusion == "full" else rng.uniform(0.7, 1.1) * radius)
        normal = np.array([-np.sin(heading[k_occ]), np.cos(heading[k_occ])])
        if np.linalg.norm(P[k_occ] - P[0]) >= 2.2 * radius + 1.5 * length:
            trees.append(Tree(P[k_occ] + side * normal, float(radius), derive_seed(spec.seed, 5, 0)))
            events.append({"kind": "tree", "frame": k_occ, "radius": float(radius)})
    # Scenery trees, kept away from the target's path (only the staged tree may occlude it).
    cand = rng.uniform(0, T, (int(60 * (T / 4096) ** 2) + 4, 2))
    radii = rng.uniform(0.6, 1.6, len(cand)) * 40 * s
    dist = np.min(np.linalg.norm(cand[:, None, :] - P[None, ::max(1, n // 100), :], axis=2), axis=1)
    for i, (c, r) in enumerate(zip(cand[dist > radii + 2.5 * length], radii[dist > radii + 2.5 * length])):
        trees.append(Tree(c, float(r), derive_seed(spec.seed, 5, i + 1)))
    return Plan(G, gain, target, distractors, trees, T), events

