"""Weight-free KCF tracker: kernel math against brute force, tracking on seeded synthetic
scenes with a known ground truth, confidence behaviour, and the MATA search-centre prior."""

import numpy as np
import pytest

from mata_eval.types import Box
from mata_eval_plugins.trackers.kcf import KCFTracker, gaussian_correlation, peak_to_sidelobe


def iou(a: Box, b: Box) -> float:
    x1, y1 = max(a.x, b.x), max(a.y, b.y)
    x2, y2 = min(a.x + a.w, b.x + b.w), min(a.y + a.h, b.y + b.h)
    inter = max(0.0, x2 - x1) * max(0.0, y2 - y1)
    return inter / (a.w * a.h + b.w * b.h - inter)


def scene(seed: int, h: int = 200, w: int = 260):
    """A smooth textured background and a high-contrast textured target patch (seeded)."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.normal(0.0, 1.0, (h, w, 3))
    bg = np.clip(110 + 25 * cv2.GaussianBlur(noise, (0, 0), 6) / 0.05, 0, 255).astype(np.uint8)
    target = rng.integers(0, 256, (40, 40, 3)).astype(np.uint8)
    target = cv2.GaussianBlur(target, (0, 0), 1.0)
    return bg, target


def render(bg, target, box: Box):
    import cv2

    img = bg.copy()
    patch = cv2.resize(target, (int(round(box.w)), int(round(box.h))), interpolation=cv2.INTER_LINEAR)
    x, y = int(round(box.x)), int(round(box.y))
    img[y:y + patch.shape[0], x:x + patch.shape[1]] = patch
    return img


def test_gaussian_correlation_matches_brute_force():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(3, 6, 5))
    y = rng.normal(size=(3, 6, 5))
    sigma = 0.7
    k = np.real(np.fft.ifft2(gaussian_correlation(np.fft.fft2(x), np.fft.fft2(y), sigma)))
    # KCF: k[i, j] = exp(-|x - shift(y, (i, j))|^2 / (sigma^2 numel)) for every cyclic shift
    for i in range(6):
        for j in range(5):
            shifted = np.roll(y, (i, j), axis=(1, 2))
            expected = np.exp(-np.sum((x - shifted) ** 2) / (sigma ** 2 * x.size))
            assert k[i, j] == pytest.approx(expected, rel=1e-9)


def test_peak_to_sidelobe_hand_value():
    r = np.zeros((8, 8))
    r[0, 0] = 10.0
    r[4, 4] = 2.0          # outside the excluded 3x3 (wrapping) neighbourhood of the peak
    side = np.zeros(64 - 9)
    side[0] = 2.0
    assert peak_to_sidelobe(r, (0, 0), 1) == pytest.approx((10 - side.mean()) / side.std())


def test_holds_a_moving_target_and_confidence_in_unit_range():
    bg, target = scene(1)
    tracker = KCFTracker()
    box = Box(60.0, 50.0, 30.0, 24.0)
    tracker.initialize(render(bg, target, box), box)
    ious, confs = [], []
    for k in range(1, 40):
        box = Box(60.0 + 3.0 * k, 50.0 + 1.5 * k, 30.0, 24.0)
        out = tracker.track(render(bg, target, box))
        ious.append(iou(out.box, box))
        confs.append(out.confidence)
    assert min(ious) > 0.6 and np.mean(ious) > 0.8
    assert all(0.0 <= c <= 1.0 for c in confs)
    assert np.mean(confs) > 0.5


def test_follows_scale_change():
    bg, target = scene(2)
    tracker = KCFTracker()
    box = Box(100.0, 80.0, 30.0, 30.0)
    tracker.initialize(render(bg, target, box), box)
    for k in range(1, 31):
        s = 30.0 * 1.015 ** k             # grows to 1.56x
        box = Box(115.0 - s / 2, 95.0 - s / 2, s, s)
        out = tracker.track(render(bg, target, box))
    # the true side grew 1.56x; a fixed-scale tracker would stay at 1.0x
    assert out.box.w / 30.0 > 1.3
    assert iou(out.box, box) > 0.6


def test_confidence_drops_under_occlusion():
    bg, target = scene(3)
    tracker = KCFTracker()
    box = Box(100.0, 80.0, 30.0, 26.0)
    img = render(bg, target, box)
    tracker.initialize(img, box)
    visible = [tracker.track(img).confidence for _ in range(3)]
    occluded = img.copy()
    occluded[70:120, 90:145] = 128        # a flat grey occluder over the whole target
    hidden = tracker.track(occluded).confidence
    assert min(visible) > 0.6
    assert hidden < 0.3


def test_prior_recovers_a_jump_beyond_the_search_window():
    bg, target = scene(4, 240, 320)
    start, jumped = Box(40.0, 40.0, 24.0, 24.0), Box(230.0, 170.0, 24.0, 24.0)

    def run(prior):
        tracker = KCFTracker()
        tracker.initialize(render(bg, target, start), start)
        tracker.track(render(bg, target, start))
        return tracker.track(render(bg, target, jumped), prior=prior)

    lost = run(None)
    found = run((jumped.cx + 6.0, jumped.cy - 5.0))   # a rough estimator prediction
    assert iou(lost.box, jumped) == 0.0
    assert iou(found.box, jumped) > 0.6
    assert found.confidence > lost.confidence


def test_bad_input_errors():
    with pytest.raises(ValueError, match="initial box"):
        KCFTracker().initialize(np.zeros((50, 50, 3), np.uint8), Box(1, 1, 0, 4))
    with pytest.raises(RuntimeError, match="before initialize"):
        KCFTracker().track(np.zeros((50, 50, 3), np.uint8))
    with pytest.raises(ValueError, match="psr_high"):
        KCFTracker(KCFTracker.Params(psr_low=5.0, psr_high=4.0))


def test_registered_as_kcf():
    from mata_eval.core.registry import load_registry

    assert load_registry().plugins["tracker"]["kcf"].cls is KCFTracker


@pytest.mark.parametrize("seq,limit,min_iou", [("uav123_10fps/wakeboard10", 60, 0.5), ("otb_Couple", 60, 0.6)])
def test_holds_real_targets(shared_data, seq, limit, min_iou):
    """Real footage against its ground truth (UAV123_10fps 10x9 px target; OTB Couple)."""
    import cv2

    folder = shared_data / "sequences" / seq
    gt = np.array([[float(v) for v in line.replace("\t", ",").split(",")]
                   for line in (folder / "groundtruth_rect.txt").read_text().splitlines() if line.strip()])
    paths = sorted((folder / "img").glob("*.jpg"))[:limit]
    tracker = KCFTracker()
    tracker.initialize(cv2.imread(str(paths[0])), Box.from_array(gt[0]))
    ious = [iou(tracker.track(cv2.imread(str(p))).box, Box.from_array(g)) for p, g in zip(paths[1:], gt[1:])]
    assert np.mean(ious) > min_iou
