"""Weight-free default tracker: a scale-aware kernelized correlation filter (KCF).

Henriques et al., "High-Speed Tracking with Kernelized Correlation Filters", TPAMI 2015: a
Gaussian-kernel ridge regression over all cyclic shifts of a padded window, solved in the
Fourier domain. Features are HOG-like (9 unsigned orientation channels pooled in 4x4 cells with
a local contrast normalisation) plus the cell's mean intensity. Scale is searched over three
scales per frame (the usual KCF scale extension). OpenCV 5 ships no KCF (contrib is not
installed), so it is written here with numpy FFTs; every step is vectorised.

Confidence in [0, 1]: the peak-to-sidelobe ratio (PSR, Bolme et al. 2010) of the response map
mapped linearly to [0, 1], times the response peak relative to its running mean over confident
frames (capped at 1). PSR alone stays high when the target leaves a window whose static
background still matches; the relative peak catches that. The model is not updated while the
confidence is below ``update_threshold`` (so an occluder does not overwrite the target).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Box, TrackerOutput

from .crop import usable_prior

_N_ORIENT = 9
_NORM_EPS = 1e-2
_COLOUR_GAIN = 1.0


def _cell_means(x: np.ndarray, cell: int) -> np.ndarray:
    """Mean over non-overlapping ``cell`` x ``cell`` blocks of an (H, W[, C]) float32 array
    (``cv2.resize`` with INTER_AREA is exactly the block mean for integer factors)."""
    h, w = x.shape[0] // cell, x.shape[1] // cell
    return cv2.resize(x[:h * cell, :w * cell], (w, h), interpolation=cv2.INTER_AREA)


def hog_like_features(gray: np.ndarray, cell: int) -> np.ndarray:
    """(C, H/cell, W/cell) features of a float32 gray patch in [0, 1]: 9 orientation channels
    (gradient magnitude soft-binned over [0, pi), averaged per cell, divided by the gradient
    energy of the 3x3 cell neighbourhood, clipped at 0.2) and the cell's mean intensity - 0.5."""
    h, w = gray.shape
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=1)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=1)
    mag, ang = cv2.cartToPolar(gx, gy)
    pos = (ang % np.pi) * (_N_ORIENT / np.pi) - 0.5       # continuous bin position
    lo = np.floor(pos)
    frac = (pos - lo).astype(np.float32)
    lo = lo.astype(np.int64) % _N_ORIENT
    hi = (lo + 1) % _N_ORIENT
    bins = np.zeros((h * w, _N_ORIENT), dtype=np.float32)
    idx = np.arange(h * w)
    bins[idx, lo.ravel()] += (mag * (1.0 - frac)).ravel()
    bins[idx, hi.ravel()] += (mag * frac).ravel()
    pooled = _cell_means(bins.reshape(h, w, _N_ORIENT), cell)            # (ch, cw, 9)
    energy = np.einsum("ijk,ijk->ij", pooled, pooled)
    local = cv2.boxFilter(energy, -1, (3, 3), normalize=False, borderType=cv2.BORDER_REPLICATE)
    hog = np.minimum(pooled / np.sqrt(local + _NORM_EPS)[..., None], 0.2)
    intensity = _cell_means(gray, cell) - 0.5
    return np.concatenate([hog, intensity[..., None]], axis=2).transpose(2, 0, 1)


def patch_features(patch: np.ndarray, cell: int, colour: bool) -> np.ndarray:
    """HOG-like channels of the patch's lightness, plus (``colour``, BGR input) the cell means
    of the CIELab a and b channels centred on 0 (chromaticity, robust to illumination)."""
    if patch.ndim == 2:
        return hog_like_features(patch.astype(np.float32) * (1.0 / 255.0), cell)
    lab = cv2.cvtColor(patch, cv2.COLOR_BGR2Lab).astype(np.float32) * (1.0 / 255.0)
    feats = hog_like_features(np.ascontiguousarray(lab[..., 0]), cell)
    if not colour:
        return feats
    ab = (_cell_means(np.ascontiguousarray(lab[..., 1:]), cell) - 0.5) * _COLOUR_GAIN
    return np.concatenate([feats, ab.transpose(2, 0, 1)], axis=0)


def gaussian_correlation(xf: np.ndarray, yf: np.ndarray, sigma: float) -> np.ndarray:
    """Fourier transform of the Gaussian kernel correlation of two (C, H, W) feature maps given
    by their 2-D FFTs (KCF eq. 31): k = exp(-max(0, |x|^2 + |y|^2 - 2 x*y) / (sigma^2 numel))."""
    hw = xf.shape[-2] * xf.shape[-1]
    xx = np.real(np.vdot(xf, xf)) / hw          # Parseval: spatial squared norm
    yy = np.real(np.vdot(yf, yf)) / hw
    xy = np.real(np.fft.ifft2((xf * np.conj(yf)).sum(axis=0)))
    d = np.maximum(0.0, xx + yy - 2.0 * xy) / xf.size
    return np.fft.fft2(np.exp(-d / (sigma ** 2)))


def peak_to_sidelobe(response: np.ndarray, peak: tuple[int, int], exclude: int) -> float:
    """PSR = (peak - mean(sidelobe)) / std(sidelobe); the sidelobe is the map minus the
    (2 exclude + 1)^2 cells around the peak (with wrap-around, the map is cyclic)."""
    h, w = response.shape
    mask = np.ones((h, w), dtype=bool)
    ys = np.arange(peak[0] - exclude, peak[0] + exclude + 1) % h
    xs = np.arange(peak[1] - exclude, peak[1] + exclude + 1) % w
    mask[np.ix_(ys, xs)] = False
    side = response[mask]
    if side.size < 2:
        return 0.0
    return float((response[peak] - side.mean()) / (side.std() + 1e-12))


def _subpixel(left: float, centre: float, right: float) -> float:
    """Vertex offset of the parabola through three samples, in [-0.5, 0.5]."""
    denom = left - 2.0 * centre + right
    if denom >= 0:
        return 0.0
    return float(np.clip(0.5 * (left - right) / denom, -0.5, 0.5))


class KCFTracker:
    """Scale-aware KCF with HOG-like + Lab features (weight-free, numpy/OpenCV); PSR-based confidence."""

    name = "kcf"
    label = "KCF"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        padding: float = param(2.0, "extra context: window side = (1 + padding) x target side")
        template_size: int = param(96, "larger side of the resampled window, pixels")
        cell_size: int = param(4, "HOG cell size, pixels of the resampled window")
        kernel_sigma: float = param(0.5, "Gaussian kernel bandwidth (KCF sigma)")
        lambda_: float = param(1e-4, "ridge regularisation (KCF lambda)")
        output_sigma_factor: float = param(0.1, "label bandwidth relative to the target size")
        learning_rate: float = param(0.02, "model interpolation factor per frame")
        scale_step: float = param(1.05, "ratio between the three searched scales")
        scale_penalty: float = param(0.97, "weight of the off-centre scales' peaks")
        psr_low: float = param(5.0, "PSR mapped to confidence 0")
        psr_high: float = param(15.0, "PSR mapped to confidence 1")
        update_threshold: float = param(0.25, "no model update below this confidence")
        min_size: float = param(4.0, "smallest allowed box side, pixels")
        colour: bool = param(True, "add CIELab a/b cell means to the HOG-like features (colour input)")

        def __post_init__(self) -> None:
            """Ranges (checked when the experiment is loaded; QA pass: a NaN padding, a zero scale
            step or an infinite learning rate failed, or quietly spoiled, every sequence)."""
            finite = ("padding", "kernel_sigma", "lambda_", "output_sigma_factor", "learning_rate", "scale_step",
                      "scale_penalty", "psr_low", "psr_high", "update_threshold", "min_size")
            for key in finite:
                if not math.isfinite(getattr(self, key)):
                    raise ValueError(f"kcf: {key}: expected a finite number, got {getattr(self, key)!r}")
            checks = {"padding": self.padding >= 0, "kernel_sigma": self.kernel_sigma > 0, "lambda_": self.lambda_ > 0,
                      "output_sigma_factor": self.output_sigma_factor > 0, "learning_rate": 0 <= self.learning_rate <= 1,
                      "scale_step": self.scale_step >= 1, "scale_penalty": 0 < self.scale_penalty <= 1,
                      "min_size": self.min_size > 0, "template_size": 16 <= self.template_size <= 1024}
            expected = {"padding": ">= 0", "learning_rate": "in [0, 1]", "scale_step": ">= 1 (1: one scale)",
                        "scale_penalty": "in (0, 1]", "template_size": "in [16, 1024] pixels"}
            for key, ok in checks.items():
                if not ok:
                    raise ValueError(f"kcf: {key}: expected {expected.get(key, '> 0')}, got {getattr(self, key)!r}")

    def __init__(self, params: "KCFTracker.Params | None" = None):
        self.params = params or self.Params()
        p = self.params
        if p.cell_size < 1 or p.template_size < 4 * p.cell_size:
            raise ValueError(f"kcf: template_size ({p.template_size}) must be >= 4 x cell_size ({p.cell_size})")
        if not p.psr_high > p.psr_low:
            raise ValueError(f"kcf: psr_high ({p.psr_high}) must exceed psr_low ({p.psr_low})")
        self._ready = False

    # --- geometry -------------------------------------------------------------------------
    def _setup(self, w: float, h: float) -> None:
        p = self.params
        win_w, win_h = w * (1 + p.padding), h * (1 + p.padding)
        s = p.template_size / max(win_w, win_h)
        cells_x = max(4, int(round(win_w * s / p.cell_size)))
        cells_y = max(4, int(round(win_h * s / p.cell_size)))
        self._cells = (cells_y, cells_x)
        self._patch = (cells_y * p.cell_size, cells_x * p.cell_size)   # (H, W) resampled window
        self._win_ratio = (win_w / w, win_h / h)                        # window / target
        hann = np.outer(np.hanning(cells_y + 2)[1:-1], np.hanning(cells_x + 2)[1:-1])
        self._cos = hann.astype(np.float32)
        # Gaussian label, peak at (0, 0) with wrap-around (KCF convention)
        target_cells = math.sqrt(w * h) * (self._patch[1] / win_w) / p.cell_size
        sigma = max(0.25, target_cells * p.output_sigma_factor)
        ys = np.roll(np.arange(cells_y) - cells_y // 2, -(cells_y // 2))
        xs = np.roll(np.arange(cells_x) - cells_x // 2, -(cells_x // 2))
        label = np.exp(-0.5 * (ys[:, None] ** 2 + xs[None, :] ** 2) / sigma ** 2)
        self._yf = np.fft.fft2(label)
        self._exclude = max(1, int(round(0.15 * min(cells_x, cells_y))))

    def _window(self, image: np.ndarray, cx: float, cy: float, w: float, h: float):
        """Resampled window around (cx, cy) of the target size (w, h); returns the feature map and
        the window's real (integer) image rectangle ``(x0, y0, ww, wh)``."""
        ww = max(2, int(round(w * self._win_ratio[0])))
        wh = max(2, int(round(h * self._win_ratio[1])))
        x0 = int(round(cx - ww / 2.0))
        y0 = int(round(cy - wh / 2.0))
        H, W = image.shape[:2]
        xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + ww, W), min(y0 + wh, H)
        if xb <= xa or yb <= ya:  # entirely outside: the nearest image pixel, replicated
            near = image[min(max(y0, 0), H - 1), min(max(x0, 0), W - 1)]
            roi = np.broadcast_to(near, (wh, ww) + image.shape[2:])
            pads = (0, 0, 0, 0)  # (padding up to the window would allocate its distance squared)
        else:
            roi = image[ya:yb, xa:xb]
            pads = (ya - y0, y0 + wh - yb, xa - x0, x0 + ww - xb)
        if any(v > 0 for v in pads):
            t, b, l, r = (max(0, v) for v in pads)
            roi = cv2.copyMakeBorder(roi, t, b, l, r, cv2.BORDER_REPLICATE)
            roi = roi[:wh, :ww] if roi.shape[0] >= wh and roi.shape[1] >= ww else cv2.resize(roi, (ww, wh))
        ph, pw = self._patch
        interp = cv2.INTER_AREA if ww > pw else cv2.INTER_LINEAR
        patch = cv2.resize(roi, (pw, ph), interpolation=interp)
        feats = patch_features(patch, self.params.cell_size, self.params.colour)
        return feats * self._cos[None], (x0, y0, ww, wh)

    # --- learning ---------------------------------------------------------------------------
    def _train(self, feats: np.ndarray, rate: float) -> None:
        xf = np.fft.fft2(feats)
        kf = gaussian_correlation(xf, xf, self.params.kernel_sigma)
        alphaf = self._yf / (kf + self.params.lambda_)
        if rate >= 1.0:
            self._xf, self._alphaf = xf, alphaf
        else:
            self._xf = (1 - rate) * self._xf + rate * xf
            self._alphaf = (1 - rate) * self._alphaf + rate * alphaf

    def _detect(self, feats: np.ndarray) -> np.ndarray:
        zf = np.fft.fft2(feats)
        kzf = gaussian_correlation(zf, self._xf, self.params.kernel_sigma)
        return np.real(np.fft.ifft2(self._alphaf * kzf))

    # --- Tracker interface ------------------------------------------------------------------
    def initialize(self, image: np.ndarray, box: Box) -> None:
        if not box.is_valid:
            raise ValueError(f"kcf: the initial box must have a positive finite size, got {box}")
        self._cx, self._cy, self._w, self._h = box.cx, box.cy, box.w, box.h
        self._img_hw = image.shape[:2]
        self._setup(box.w, box.h)
        feats, _ = self._window(image, self._cx, self._cy, self._w, self._h)
        self._train(feats, 1.0)
        self._peak_ref: float | None = None     # running mean of the response peak
        self._ready = True

    def track(self, image: np.ndarray, prior: tuple[float, float] | None = None) -> TrackerOutput:
        if not self._ready:
            raise RuntimeError("kcf: track() called before initialize()")
        p = self.params
        prior = usable_prior(prior, self._w, self._h, *image.shape[:2])
        cx, cy = (self._cx, self._cy) if prior is None else prior
        best = None
        for scale in (1.0, 1.0 / p.scale_step, p.scale_step):
            w, h = self._w * scale, self._h * scale
            feats, rect = self._window(image, cx, cy, w, h)
            resp = self._detect(feats)
            iy, ix = np.unravel_index(int(np.argmax(resp)), resp.shape)
            value = float(resp[iy, ix]) * (1.0 if scale == 1.0 else p.scale_penalty)
            if best is None or value > best[0]:
                best = (value, scale, resp, (iy, ix), rect)
        _, scale, resp, (iy, ix), (x0, y0, ww, wh) = best
        rows, cols = resp.shape
        dy = iy + _subpixel(resp[iy - 1, ix], resp[iy, ix], resp[(iy + 1) % rows, ix])
        dx = ix + _subpixel(resp[iy, ix - 1], resp[iy, ix], resp[iy, (ix + 1) % cols])
        if dy > rows / 2:
            dy -= rows
        if dx > cols / 2:
            dx -= cols
        ph, pw = self._patch
        new_cx = x0 + ww / 2.0 + dx * p.cell_size * ww / pw
        new_cy = y0 + wh / 2.0 + dy * p.cell_size * wh / ph
        H, W = image.shape[:2]
        new_cx = float(np.clip(new_cx, 0.0, W - 1.0))
        new_cy = float(np.clip(new_cy, 0.0, H - 1.0))
        new_w = float(np.clip(self._w * scale, p.min_size, W))
        new_h = float(np.clip(self._h * scale, p.min_size, H))

        psr = peak_to_sidelobe(resp, (iy, ix), self._exclude)
        peak = float(resp[iy, ix])
        sharpness = float(np.clip((psr - p.psr_low) / (p.psr_high - p.psr_low), 0.0, 1.0))
        if self._peak_ref is None:
            self._peak_ref = max(peak, 1e-6)
        relative_peak = float(np.clip(peak / self._peak_ref, 0.0, 1.0))
        confidence = sharpness * relative_peak
        self._cx, self._cy, self._w, self._h = new_cx, new_cy, new_w, new_h
        if confidence >= p.update_threshold:
            self._peak_ref = 0.9 * self._peak_ref + 0.1 * peak
            feats, _ = self._window(image, new_cx, new_cy, new_w, new_h)
            self._train(feats, p.learning_rate)
        return TrackerOutput(
            box=Box.from_center(new_cx, new_cy, new_w, new_h),
            confidence=confidence,
            score_map=np.fft.fftshift(resp).astype(np.float32),
            extra={"psr": psr, "peak": peak, "relative_peak": relative_peak, "scale": float(scale),
                   "search_x": float(x0), "search_y": float(y0), "search_w": float(ww), "search_h": float(wh)},
        )


@hookimpl
def mata_eval_trackers():
    return [KCFTracker]
