"""How the scene moves: the target's and distractors' kinematics on the ground and the camera's
pursuit (lag, yaw, tilt, zoom, roll, shake, manoeuvres, out-of-view spells), as the per-frame
ground-to-image homographies ``G_k`` of a :class:`Plan` (paper section 2.2: the true inter-frame
homography is ``H_k = G_k G_{k-1}^-1``)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from . import texture as tex
from .spec import REF_WIDTH, SequenceSpec, derive_seed


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _smoothing_kernel(corr: float) -> np.ndarray:
    k = np.exp(-0.5 * (np.arange(-3 * int(corr) - 1, 3 * int(corr) + 2) / max(corr, 1e-3)) ** 2)
    return k / np.sqrt((k ** 2).sum())


def _smooth_noise(rng: np.random.Generator, n: int, scale: float, corr: float) -> np.ndarray:
    """Gaussian-smoothed white noise with std ``scale`` and correlation length ``corr`` frames."""
    w = rng.standard_normal(n + 6 * int(corr) + 2)
    return scale * np.convolve(w, _smoothing_kernel(corr), mode="valid")[:n]


def _smooth_noise_mean_variance(n: int, corr: float) -> float:
    """Variance of the mean over ``n`` frames of unit :func:`_smooth_noise` (exact, from the
    kernel's autocorrelation ``rho``: ``sum_d (n - |d|) rho(d) / n^2``)."""
    k = _smoothing_kernel(corr)
    rho = np.correlate(k, k, mode="full")  # lags -(len-1) .. len-1, rho(0) = 1
    lags = np.arange(-(len(k) - 1), len(k))
    keep = np.abs(lags) < n
    return float(np.sum((n - np.abs(lags[keep])) * rho[keep]) / n ** 2)


def _spells(rng: np.random.Generator, n: int, duty: float, corr: float) -> np.ndarray:
    """An on/off switch per frame in [0, 1]: on in spells, a fraction ``duty`` of the time, with a
    correlation of ``corr`` frames (a unit :func:`_smooth_noise` above its ``1 - duty`` quantile,
    ramped over a tenth of its std so that a spell starts and ends smoothly)."""
    if duty >= 1.0:
        return np.ones(n)
    g = _smooth_noise(rng, n, 1.0, corr)
    return np.clip((g - NormalDist().inv_cdf(1.0 - duty)) / 0.1 + 0.5, 0.0, 1.0)


def _poisson_quantile(mean: float, q: float) -> int:
    """The smallest count whose Poisson(``mean``) CDF reaches ``q`` (normal approximation past a
    mean of 500, where ``exp(-mean)`` underflows: sequences of over an hour)."""
    if mean > 500:
        return max(0, round(mean + math.sqrt(mean) * NormalDist().inv_cdf(q)))
    k, p = 0, math.exp(-mean)
    cdf = p
    while cdf < q:
        k += 1
        p *= mean / k
        cdf += p
    return k


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


@dataclass(frozen=True, eq=False)
class CameraPath:
    """The camera of a sequence, per frame: the ground point it looks at (n, 2), yaw, off-nadir
    tilt and roll (rad), zoom (focal length / altitude), and the staged events (manoeuvres,
    re-framing pans, out-of-view spells) as ``{"kind", "frame", "frames"}``."""

    look_at: np.ndarray
    yaw: np.ndarray
    tilt: np.ndarray
    roll: np.ndarray
    zoom: np.ndarray
    events: tuple[dict, ...]


def _manoeuvres(rng: np.random.Generator, spec: SequenceSpec, yaw: np.ndarray, logzoom: np.ndarray,
                push: np.ndarray, events: list) -> None:
    """``spec.manoeuvres`` sudden camera moves over 3-6 frames: a pan of 0.15-0.3 image widths
    (added to ``push``, per frame), a 15-35 deg yaw jerk or a x1.2-1.4 zoom jump (in place)."""
    n, W = spec.n_frames, spec.width
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


def _look_away(rng: np.random.Generator, spec: SequenceSpec, length: float, zoom: np.ndarray,
               events: list) -> np.ndarray:
    """The out-of-view spell, (n, 2) added to the look-at point: pushed away (raised-cosine
    rise, hold, fall) by more than the half diagonal of the image, so the target leaves it."""
    n, W, H = spec.n_frames, spec.width, spec.height
    rise = int(np.clip(round(0.05 * n), 2, 15))
    hold = int(np.clip(round(0.12 * n), 2, 40))
    low = max(1, int(0.25 * n))   # (a short sequence, n <= 8, has a spell running past its end)
    k0 = int(rng.integers(low, max(low + 1, n - 2 * rise - hold)))
    k = np.arange(n)
    bump = _smoothstep((k - k0) / rise) - _smoothstep((k - k0 - rise - hold) / rise)
    direction = rng.uniform(0, 2 * np.pi)
    D = 1.4 * (0.5 * math.hypot(W, H) + 2 * length) / zoom.min()
    events.append({"kind": "out_of_view", "frame": k0, "frames": 2 * rise + hold})
    return bump[:, None] * D * np.array([np.cos(direction), np.sin(direction)])


def legacy_camera(rng: np.random.Generator, spec: SequenceSpec, P: np.ndarray, length: float) -> CameraPath:
    """Generator version 3's camera (``motion: legacy``), draw for draw: first-order pursuit of
    the target with gain 0.08 per frame, slow yaw/tilt/zoom/roll drifts, 0.6 px shake, the
    manoeuvres and the out-of-view spell. The target sits nearly still in the image (issue 15)."""
    n, s = spec.n_frames, spec.width / REF_WIDTH
    yaw = rng.uniform(0, 2 * np.pi) + np.cumsum(_smooth_noise(rng, n, 0.004, 20))
    tilt = np.clip(np.deg2rad(rng.uniform(0, 18)) + _smooth_noise(rng, n, np.deg2rad(4), 40), 0, np.deg2rad(28))
    logzoom = np.log(rng.uniform(0.95, 1.35)) + np.cumsum(_smooth_noise(rng, n, 0.004, 30))
    roll = _smooth_noise(rng, n, np.deg2rad(1.0), 25)
    push = np.zeros((n, 2))
    events: list[dict] = []
    _manoeuvres(rng, spec, yaw, logzoom, push, events)
    zoom = np.exp(np.clip(logzoom, np.log(0.75), np.log(1.9)))
    shake = np.stack([_smooth_noise(rng, n, 0.6 * s, 3), _smooth_noise(rng, n, 0.6 * s, 3)], axis=1)
    alpha = 0.08
    L = np.empty((n, 2))
    L[0] = P[0]
    for k in range(1, n):
        L[k] = L[k - 1] + alpha * (P[k] - L[k - 1]) + push[k]
    L += shake
    if spec.out_of_view:
        L += _look_away(rng, spec, length, zoom, events)
    return CameraPath(L, yaw, tilt, roll, zoom, tuple(events))


@dataclass(frozen=True)
class DroneCamera:
    """Parameters of :func:`drone_camera` (``motion: uav123``), in seconds and image units so that
    the camera does not depend on the frame rate or the render size. Chosen on the UAV123 ground
    truth's image-plane statistics and its 10 Hz perfect-tracker NT2F (``benchmarks/oracle.py``),
    pooled over 400 sequences (seeds 0-9, 40 each, at 320x180; ``reframe_rate`` 0.16 -> 0.12 in
    generator 5; the zoom in spells, ``zoom_duty`` 0.8, in generator 6, chosen on the share of
    10-frame pairs whose box keeps its size, with the ground truth on UAV123's whole-pixel grid;
    the handheld ``jitter`` 1 -> 0.75 px in generator 7, on the 1-frame shift on that grid);
    camera rates checked against grid-LK homographies of real drone footage
    (docs/decisions/data.md)."""

    yaw_rate: float = 0.12                   # rad/s: std of the smooth yaw-rate drift (corr. 0.67 s)
    zoom_rate: float = 0.09                  # 1/s: median std of the log-zoom rate drift while zooming (corr. 1 s)
    zoom_spread: float = 0.6                 # std of its log across sequences
    zoom_duty: float = 0.8                   # fraction of the time the operator zooms (spells, corr. 1 s)
    lag: tuple[float, float] = (0.3, 0.8)    # s: the camera matches the target's velocity this late
    recentre: tuple[float, float] = (1.5, 3.0)  # s: and brings the pursuit point back this slowly
    wander: float = 0.45                     # target sizes/s: median std of the framing error's velocity
    wander_spread: float = 0.4               # std of its log across operators, besides their spells' level
    wander_burst: float = 1.5                # std of its log in the spells (corr. 2 s; see drone_camera)
    wander_corr: float = 0.15                # s: correlation time of that velocity
    wander_leak: float = 4.0                 # s: the framing error leaks back to zero over this time
    reframe_rate: float = 0.12               # re-framing pans per second (Poisson)
    reframe_size: tuple[float, float] = (0.03, 0.12)  # image widths, log-uniform
    reframe_time: tuple[float, float] = (0.25, 0.6)   # s: duration of a pan
    max_offset: float = 0.35                 # image heights: the framing error saturates here
    jitter: float = 0.75                     # px at 1280 wide: handheld-like shake (corr. 2 frames)


DRONE = DroneCamera()


def drone_camera(rng: np.random.Generator, spec: SequenceSpec, P: np.ndarray, length: float,
                 c: DroneCamera = DRONE) -> CameraPath:
    """A camera operated like UAV123's (``motion: uav123``, the default; values in
    :class:`DroneCamera`). The look-at point is the pursuit point plus a *framing error* that
    the operator never quite cancels:

    - *pursuit*: the camera velocity follows the target's with a first-order lag plus a slow
      re-centring term, so the target's turns and accelerations show in the image;
    - *wander*: the framing error drifts with a smooth random velocity leaking back to zero;
      its scale, in target sizes per second, is the operator's *pace* (log-normal across
      sequences) times calm and busy *spells* within the sequence (log-normal, correlation 2 s):
      some stretches hold the target still, others let it swim;
    - *re-framing pans* (Poisson in time, a few hundredths to a tenth of the image width in a
      fraction of a second): the moves that make a box a few frames old miss the target.

    The per-sequence draws that set how fast a sequence moves are read from quantiles of the
    spec, so that a suite can spread them evenly (:func:`.spec.spread_quantiles`): the pace at
    quantile ``spec.pace``, the number of pans at quantile ``spec.pans`` of its Poisson law and
    the zoom rate at ``spec.zooming``. The spells are a smooth Gaussian process of which only
    the shape in time is random: its mean over the sequence (a level that would make the whole
    sequence busy or calm) is folded into the pace's log-normal spread, with its exact variance
    (:func:`_smooth_noise_mean_variance`), and its spread within the sequence is set to its
    expected value, so every sequence has the same mix of busy and calm. (Generator 5;
    generator 4 drew these at random per sequence, from the same laws on average, and a
    20-sequence suite was a noisy sample of the model.)

    Further:
    - the framing error is saturated at ``max_offset`` (the target stays in view unless an
      out-of-view spell is staged), plus a handheld-like shake;
    - yaw, tilt and roll drift smoothly; the zoom drifts in spells (a ``zoom_duty`` share of
      the time, :func:`_spells`) and holds in between, as UAV123's targets often keep their
      size for a while (generator 6; before, it drifted all the time and the 10-frame scale
      change was too rarely small);
    - the spec's manoeuvres and out-of-view spell are staged as in :func:`legacy_camera`.
    """
    n, W, fps = spec.n_frames, spec.width, spec.fps
    s = W / REF_WIDTH
    yaw = rng.uniform(0, 2 * np.pi) + np.cumsum(_smooth_noise(rng, n, c.yaw_rate / fps, 0.67 * fps))
    tilt = np.clip(np.deg2rad(rng.uniform(0, 18)) + _smooth_noise(rng, n, np.deg2rad(4), 1.33 * fps), 0, np.deg2rad(28))
    zoom_rate = c.zoom_rate * math.exp(c.zoom_spread * NormalDist().inv_cdf(spec.zooming))
    logzoom = np.log(rng.uniform(0.95, 1.35)) + np.cumsum(_smooth_noise(rng, n, zoom_rate / fps, 1.0 * fps)
                                                          * _spells(np.random.default_rng(derive_seed(spec.seed, 9)),
                                                                    n, c.zoom_duty, 1.0 * fps))
    roll = _smooth_noise(rng, n, np.deg2rad(1.0), 0.83 * fps)
    push = np.zeros((n, 2))
    events: list[dict] = []
    _manoeuvres(rng, spec, yaw, logzoom, push, events)
    zoom = np.exp(np.clip(logzoom, np.log(0.75), np.log(1.9)))

    # Pursuit: velocity matched with a lag, position re-centred slowly.
    lag, recentre = (max(1.0, rng.uniform(*r) * fps) for r in (c.lag, c.recentre))  # in frames
    v_target = np.diff(P, axis=0, prepend=P[:1])
    L = np.empty((n, 2))
    L[0] = P[0]
    u = v_target[1] if n > 1 else np.zeros(2)
    for k in range(1, n):
        u = u + (v_target[k] + (P[k] - L[k - 1]) / recentre - u) / lag
        L[k] = L[k - 1] + u

    # Framing error (ground units): wander + re-framing pans, saturated.
    size = 0.68 * length  # sqrt(w h) of the target's box at zoom 1
    spells = _smooth_noise(rng, n, 1.0, 2.0 * fps)
    level = _smooth_noise_mean_variance(n, 2.0 * fps)
    pace_spread = math.hypot(c.wander_spread, c.wander_burst * math.sqrt(level))
    sigma = c.wander * math.exp(pace_spread * NormalDist().inv_cdf(spec.pace)) * size / fps
    spells = (spells - spells.mean()) / max(spells.std(), 1e-9) * math.sqrt(1.0 - level)  # E[sample var]
    busy = np.exp(c.wander_burst * spells)
    v = np.stack([_smooth_noise(rng, n, sigma, c.wander_corr * fps) for _ in range(2)], axis=1) * busy[:, None]
    keep = 1.0 - 1.0 / (c.wander_leak * fps)
    err = np.zeros((n, 2))
    for k in range(1, n):
        err[k] = keep * err[k - 1] + v[k] + push[k]  # a manoeuvre's pan is a framing error too
    for _ in range(_poisson_quantile(c.reframe_rate * n / fps, spec.pans)):
        k0 = int(rng.integers(1, n))
        d = max(2, int(round(rng.uniform(*c.reframe_time) * fps)))
        size_px = math.exp(rng.uniform(*np.log(c.reframe_size))) * W
        a = rng.uniform(0, 2 * np.pi)
        err += _smoothstep((np.arange(n) - k0 + 1) / d)[:, None] * (size_px / zoom[k0]) * np.array([np.cos(a), np.sin(a)])
        events.append({"kind": "reframe", "frame": k0, "frames": d})
    reach = c.max_offset * spec.height / zoom[:, None]
    norm = np.linalg.norm(err, axis=1, keepdims=True)
    err *= reach * np.tanh(norm / reach) / np.maximum(norm, 1e-12)
    shake = np.stack([_smooth_noise(rng, n, c.jitter * s, 2) for _ in range(2)], axis=1) / zoom[:, None]
    L = L + err + shake
    if spec.out_of_view:
        L += _look_away(rng, spec, length, zoom, events)
    return CameraPath(L, yaw, tilt, roll, zoom, tuple(events))


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

    Z = 1000.0 * s
    if spec.motion == "legacy":
        cam = legacy_camera(rng, spec, P, length)
    else:
        cam = drone_camera(np.random.default_rng(derive_seed(spec.seed, 7)), spec, P, length)
    yaw, zoom, events = cam.yaw, cam.zoom, list(cam.events)
    G = np.stack([camera(cam.look_at[k], Z, yaw[k], cam.tilt[k], cam.roll[k], Z * zoom[k], W, H) for k in range(n)])

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

