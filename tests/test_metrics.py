"""Metrics against independent facts: hand-computed IoU / NT2F cases, an OpenCV polygon-clipping
reference for IoU, a hand-built sequence whose score under each toolkit's policy is worked out by
hand from EVAL_TOOLKITS.md, and the published DTB70 numbers of SiamAPN++."""

from __future__ import annotations

import os
import re
import subprocess
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from mata_eval.score import metrics as M


def boxes(*rows):
    return np.array(rows, dtype=float).reshape(-1, 4)


# --- IoU -------------------------------------------------------------------------------------


def test_iou_hand_cases():
    gt = boxes([0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10])
    pred = boxes([0, 0, 10, 10],   # identical: 1
                 [5, 0, 10, 10],   # half shifted: 50 / 150
                 [2, 2, 5, 5],     # inside: 25 / 100
                 [10, 0, 10, 10],  # touching edge: 0
                 [30, 30, 4, 4])   # disjoint: 0
    np.testing.assert_allclose(M.iou(pred, gt), [1.0, 1 / 3, 0.25, 0.0, 0.0])


def test_iou_of_missing_or_empty_prediction_is_zero():
    gt = boxes([0, 0, 10, 10], [0, 0, 10, 10], [0, 0, 10, 10])
    pred = boxes([np.nan] * 4, [0, 0, 0, 0], [0, 0, -5, -5])
    assert M.iou(pred, gt).tolist() == [0.0, 0.0, 0.0]


def test_iou_matches_opencv_polygon_intersection():
    rng = np.random.default_rng(7)
    n = 300
    a = np.c_[rng.uniform(0, 50, (n, 2)), rng.uniform(1, 40, (n, 2))]
    b = np.c_[a[:, :2] + rng.normal(0, 10, (n, 2)), a[:, 2:] * rng.uniform(0.5, 1.5, (n, 2))]
    ref = []
    for p, g in zip(a, b):
        r = lambda x: ((x[0] + x[2] / 2, x[1] + x[3] / 2), (x[2], x[3]), 0.0)  # noqa: E731
        kind, pts = cv2.rotatedRectangleIntersection(r(p), r(g))
        inter = cv2.contourArea(pts) if pts is not None and len(pts) > 2 else 0.0
        ref.append(inter / (p[2] * p[3] + g[2] * g[3] - inter))
    np.testing.assert_allclose(M.iou(a, b), ref, atol=1e-4)


def test_iou_rejects_bad_shapes():
    with pytest.raises(ValueError, match=r"\(N, 4\)"):
        M.iou(np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="pred has 2 boxes, gt has 3"):
        M.iou(np.zeros((2, 4)), np.zeros((3, 4)))


# --- NT2F (eq. nt2f) -------------------------------------------------------------------------


def shifted(gt: np.ndarray, dx: np.ndarray) -> np.ndarray:
    p = gt.copy()
    p[:, 0] += dx
    return p


def test_nt2f_first_failure_over_n():
    # IoU per frame of a 10x10 box shifted by dx: (10 - dx) / (10 + dx); dx >= 10 -> 0 (failure)
    gt = np.tile([0.0, 0.0, 10.0, 10.0], (5, 1))
    s = M.score_sequence(shifted(gt, np.array([0, 2, 5, 10, 0])), gt)
    assert s.nt2f == pytest.approx(3 / 5)  # T_f = 3 (the tracker recovers at 4: ignored)
    assert s.failure_frame == 3


def test_nt2f_never_failing_is_one_and_failing_at_start_is_zero():
    gt = np.tile([0.0, 0.0, 10.0, 10.0], (4, 1))
    assert M.score_sequence(shifted(gt, np.array([0, 9, 9, 9])), gt).nt2f == 1.0
    s = M.score_sequence(shifted(gt, np.array([20, 0, 0, 0])), gt)
    assert s.nt2f == 0.0 and s.failure_frame == 0


def test_nt2f_tau_threshold():
    gt = np.tile([0.0, 0.0, 10.0, 10.0], (4, 1))
    pred = shifted(gt, np.array([0, 5, 0, 0]))  # IoU 1/3 at frame 1
    assert M.score_sequence(pred, gt).nt2f == 1.0
    assert M.score_sequence(pred, gt, tau=0.5).nt2f == pytest.approx(1 / 4)


def test_nt2f_frames_without_valid_ground_truth_never_fail():
    gt = np.tile([0.0, 0.0, 10.0, 10.0], (6, 1))
    gt[2] = np.nan          # target absent: can neither fail nor succeed
    gt[3, 2] = 0.0          # zero-width ground truth: same
    pred = shifted(gt, np.array([0, 0, 50, 50, 0, 50]))
    pred[2] = [50, 50, 10, 10]
    s = M.score_sequence(pred, gt)
    # eq. nt2f (mata-paper.tex L499-505): first failure at frame 5 of a 6-frame sequence
    assert s.nt2f == pytest.approx(5 / 6)
    assert s.failure_frame == 5
    assert s.n_excluded == 2 and s.n_invalid_gt == 2 and s.n_scored == 6
    # nt2f-valid: valid frames 0, 1, 4, 5 -> the failure is the 4th valid frame: T_f = 3, N = 4
    valid_only = M.score_sequence(pred, gt, profile="nt2f-valid")
    assert valid_only.nt2f == pytest.approx(3 / 4) and valid_only.failure_frame == 5
    assert valid_only.msr == s.msr and valid_only.sr == s.sr  # NT2F is all it changes


def test_scored_and_annotated_masks_select_frames():
    gt = np.tile([0.0, 0.0, 10.0, 10.0], (8, 1))
    dx = np.array([0, 50, 0, 50, 0, 50, 50, 0])  # odd frames fail, and frame 6
    pred = shifted(gt, dx)
    dsp = np.arange(8) % 2 == 0                  # DSP keeps frames 0, 2, 4, 6
    s = M.score_sequence(pred, gt, scored=dsp)
    assert s.n_scored == 4 and s.n_frames == 8
    assert s.nt2f == pytest.approx(6 / 8) and s.failure_frame == 6   # frame 6 of 8
    assert M.score_sequence(pred, gt, scored=dsp, profile="nt2f-valid").nt2f == pytest.approx(3 / 4)  # 4th of 4
    assert s.sr == pytest.approx(3 / 4)
    ann = np.zeros(8, bool)
    ann[[0, 4, 7]] = True                        # sparse ground truth: only these frames
    s = M.score_sequence(pred, gt, annotated=ann)
    assert s.n_scored == 3 and s.sr == 1.0 and s.nt2f == 1.0
    s = M.score_sequence(pred, gt, scored=dsp, annotated=ann)  # both: frames 0 and 4
    assert s.n_scored == 2 and s.nt2f == 1.0


def test_mask_length_is_checked():
    gt = np.tile([0.0, 0.0, 10.0, 10.0], (3, 1))
    with pytest.raises(ValueError, match="scored mask has 2 entries, the sequence has 3 frames"):
        M.score_sequence(gt, gt, scored=[True, False])


def test_length_mismatch_is_an_error_by_default():
    gt = np.tile([0.0, 0.0, 10.0, 10.0], (3, 1))
    with pytest.raises(ValueError, match="predictions have 2 rows but the ground truth has 3"):
        M.score_sequence(gt[:2], gt)


# --- curves, perfect tracker, profiles --------------------------------------------------------


@pytest.mark.parametrize("profile", sorted(M.PROFILES))
def test_perfect_tracker_scores_20_of_21(profile):
    """IoU = 1 never passes the last threshold (IoU > 1.0): AUC 20/21 in every toolkit."""
    gt = np.c_[np.arange(50.0), np.arange(50.0), np.full(50, 30.0), np.full(50, 20.0)] + 5
    s = M.score_sequence(gt.copy(), gt, profile=profile)
    assert s.msr == pytest.approx(20 / 21)
    assert s.sr == s.precision20 == s.pr == s.nt2f == 1.0
    assert len(s.success_curve) == 21 and len(s.precision_curve) == 51 and len(s.norm_precision_curve) == 51


def test_threshold_grids():
    assert M.PYSOT_IOU_GRID[10] == 0.5 and M.PYSOT_IOU_GRID[20] == 1.0
    assert M.PYSOT_IOU_GRID[6] == 0.30000000000000004  # numpy's arange noise, kept on purpose
    assert M.PIXEL_GRID[20] == 20.0 and M.NORM_GRID[20] == 0.2
    assert M.PYTRACKING_IOU_GRID[15] > 0.75 and M.PYTRACKING_IOU_GRID[14] == M.PYSOT_IOU_GRID[14]


def test_profiles_are_the_named_ones():
    assert set(M.PROFILES) == {"default", "nt2f-valid", "pysot", "pysot-toolkit", "got10k", "pytracking", "mmtracking"}
    with pytest.raises(KeyError, match="available: default"):
        M.get_profile("vot2099")


def hand_case():
    """10 frames, GT (10, 10, 20, 20) except frame 4 (NaN: the tracker keeps a box) and frame 7
    (x = 0). Prediction: frame 0 shifted 10 px (IoU 1/3, error 10 px, normalised 0.5), frame 7
    shifted 5 px (IoU 0.6, 5 px, 0.25), frame 9 zero-size at (10, 10) (IoU 0, 14.1 px, 0.71),
    exact elsewhere."""
    gt = np.tile([10.0, 10.0, 20.0, 20.0], (10, 1))
    gt[4] = np.nan
    gt[7] = [0, 10, 20, 20]
    pred = np.tile([10.0, 10.0, 20.0, 20.0], (10, 1))
    pred[0] = [20, 10, 20, 20]
    pred[7] = [5, 10, 20, 20]
    pred[9] = [10, 10, 0, 0]
    return pred, gt


# Worked out by hand from EVAL_TOOLKITS.md. Success sums over the 21 thresholds (IoU > t):
# IoU 1 passes 20, IoU 1/3 passes 7 (t <= 0.30000000000000004), IoU 0.6 passes 12 (t12 is
# 0.6000000000000001), IoU 0 passes none.
HAND_EXPECTED = {
    #                msr             sr      p@20    pr      nt2f  excluded
    # NT2F: the zero-size prediction at frame 9 fails (frame 4 cannot): T_f = 9, N = 10
    # skip NaN (frame 4): D = 9; 7 + 6*20 + 12 = 139
    "default":       (139 / 189, 7 / 9, 1.0, 6 / 9, 9 / 10, 1),
    # NT2F over the 9 frames with a target: the failure is the 9th of them, T_f = 8
    "nt2f-valid":    (139 / 189, 7 / 9, 1.0, 6 / 9, 8 / 9, 1),
    # NaN GT = failure for success, hit for precision; D = 10
    "pysot":         (139 / 210, 7 / 10, 1.0, 7 / 10, 9 / 10, 0),
    # also x = 0 (frame 7) is a success failure: 7 + 6*20 = 127
    "pysot-toolkit": (127 / 210, 6 / 10, 1.0, 7 / 10, 9 / 10, 0),
    # same masks as pysot for this case (centre x + w/2 = 10 > 0 at frame 7)
    "mmtracking":    (139 / 210, 7 / 10, 1.0, 7 / 10, 9 / 10, 0),
    # NaN row removed (D = 9), frame 0 := GT (20): 20 + 6*20 + 12 = 152
    "got10k":        (152 / 189, 8 / 9, 1.0, 7 / 9, 9 / 10, 1),
    # frame 0 := GT, zero-size frame 9 := frame 8 (IoU 1); frames 4, 7 invalid (x = 0):
    # success failure, (normalised) precision hit; 20 + 6*20 + 20 = 160
    "pytracking":    (160 / 210, 8 / 10, 1.0, 10 / 10, 1.0, 0),
}


@pytest.mark.parametrize("profile", sorted(HAND_EXPECTED))
def test_profiles_on_hand_built_case(profile):
    pred, gt = hand_case()
    s = M.score_sequence(pred, gt, profile=profile)
    msr, sr, p20, pr, nt2f, excluded = HAND_EXPECTED[profile]
    assert s.msr == pytest.approx(msr, abs=1e-12)
    assert s.sr == pytest.approx(sr, abs=1e-12)
    assert s.precision20 == pytest.approx(p20, abs=1e-12)
    assert s.pr == pytest.approx(pr, abs=1e-12)
    assert s.nt2f == pytest.approx(nt2f, abs=1e-12)
    assert s.n_excluded == excluded
    assert s.n_invalid_gt == 1  # the NaN row, whatever the profile does with it


def test_got10k_truncates_and_pytracking_pads_mismatched_lengths():
    gt = np.tile([10.0, 10.0, 20.0, 20.0], (4, 1))
    short = gt[:3].copy()
    s = M.score_sequence(short, gt, profile="got10k")  # scored on the 3 common frames
    assert s.n_scored == 3 and s.sr == 1.0
    s = M.score_sequence(short, gt, profile="pytracking")  # 4th frame padded with a zero box
    assert s.n_scored == 4 and s.sr == pytest.approx(3 / 4)


# --- aggregation and frequencies -------------------------------------------------------------


def seq_scores(nt2f_ratio: float, n: int = 10) -> M.SequenceScores:
    gt = np.tile([0.0, 0.0, 10.0, 10.0], (n, 1))
    dx = np.zeros(n)
    dx[int(round(nt2f_ratio * n)):] = 50
    return M.score_sequence(shifted(gt, dx), gt)


def test_aggregate_means_attributes_and_groups():
    a, b, c = seq_scores(1.0), seq_scores(0.5), seq_scores(0.2)
    agg = M.aggregate([(a, {"FOC", "FM"}), (b, {"POC"}), (c, {"aoc", "SV"})])
    assert agg.overall.n_sequences == 3
    assert agg.overall.nt2f == pytest.approx((1.0 + 0.5 + 0.2) / 3)
    assert agg.overall.sr == pytest.approx((1.0 + 0.5 + 0.2) / 3)
    # occlusion = FOC or POC or AOC (case-insensitive): all three
    assert agg.groups["occlusion"].n_sequences == 3
    assert agg.groups["high dynamic"].nt2f == pytest.approx(1.0)
    assert agg.groups["distractor"].n_sequences == 0 and np.isnan(agg.groups["distractor"].nt2f)
    assert set(agg.attributes) == {"FOC", "FM", "POC", "aoc", "SV"}
    assert agg.attributes["POC"].nt2f == pytest.approx(0.5)
    custom = M.aggregate([(a, {"FOC"}), (b, {"POC"})], groups={"full occlusion": ["foc"]})
    assert list(custom.groups) == ["full occlusion"] and custom.groups["full occlusion"].nt2f == 1.0


def test_aggregate_mean_curve_is_mean_of_sequence_curves():
    a, b = seq_scores(1.0), seq_scores(0.3)
    agg = M.aggregate([(a, ()), (b, ())])
    np.testing.assert_allclose(agg.overall.success_curve, (a.success_curve + b.success_curve) / 2)
    assert agg.overall.msr == pytest.approx(np.mean(agg.overall.success_curve))


def test_block_frequencies_scheduled_and_wall_clock():
    n, fps = 30, 30.0
    tracker = np.full(n, np.nan)
    tracker[::3] = 50.0                   # starts every 3rd frame (10 Hz), 50 ms per call
    ego = np.full(n, 4.0)                 # every frame, 4 ms
    f = M.block_frequencies({"tracker": tracker, "egomotion": ego}, n, fps)
    assert f["tracker"].scheduled_hz == pytest.approx(10.0)
    assert f["tracker"].wall_hz == pytest.approx(20.0)
    assert f["egomotion"].scheduled_hz == pytest.approx(30.0)
    assert f["egomotion"].wall_hz == pytest.approx(250.0)
    # two sequences: one of 1 s at 10 Hz, one of 2 s at 5 Hz -> 20 starts in 3 s
    slow = np.full(60, np.nan)
    slow[::6] = 100.0
    both = M.combine_frequencies([f, M.block_frequencies({"tracker": slow}, 60, fps)])
    assert both["tracker"].scheduled_hz == pytest.approx(20 / 3)
    assert both["tracker"].wall_hz == pytest.approx(1000 * 20 / (10 * 50 + 10 * 100))


def test_sequence_scores_round_trip_through_dict():
    pred, gt = hand_case()
    s = M.score_sequence(pred, gt)
    back = M.SequenceScores.from_dict(s.to_dict())
    assert back.msr == s.msr and back.nt2f == s.nt2f and back.failure_frame == s.failure_frame
    np.testing.assert_array_equal(back.precision_curve, s.precision_curve)


# --- published numbers ------------------------------------------------------------------------


def _read_boxes(text: str) -> np.ndarray:
    return np.array([[float(v) for v in re.split(r"[,\s]+", line.strip())]
                     for line in text.splitlines() if line.strip()])


def test_dtb70_siamapnpp_published_auc_and_precision(shared_data):
    """SiamAPN++ on DTB70: AUC 0.594, precision 0.789 (pysot-toolkit one-pass evaluation)."""
    ann = shared_data / "annotations" / "DTB70"
    items = []
    with zipfile.ZipFile(shared_data / "results" / "DTB70.zip") as z:
        for f in sorted(ann.glob("*.txt")):
            if f.name == "ATTRIBUTE_ORDER.txt":
                continue
            pred = _read_boxes(z.read(f"DTB70/SiamAPN++/{f.name}").decode())
            items.append((M.score_sequence(pred, _read_boxes(f.read_text()), profile="pysot-toolkit"), ()))
    assert len(items) == 70
    agg = M.aggregate(items).overall
    assert round(agg.msr, 3) == 0.594
    assert round(agg.precision20, 3) == 0.789


def _mmtracking_fixture() -> Path | None:
    """An mmtracking checkout (``MATA_MMTRACKING_REPO``); its test fixture is not vendored here."""
    root = os.environ.get("MATA_MMTRACKING_REPO")
    return Path(root) if root else None


def test_mmtracking_golden_numbers():
    """mmtracking's tests/test_data/test_datasets/test_sot_dataset.py asserts success 67.524,
    norm precision 70.0, precision 50.0 on its two-video fixture; got10k / pytracking give 68.667
    (frame 0 replaced by GT). Needs a checkout: MATA_MMTRACKING_REPO=/path/to/mmtracking."""
    root = _mmtracking_fixture()
    if root is None:
        pytest.skip("set MATA_MMTRACKING_REPO to an mmtracking checkout to run its golden test")
    base = "tests/data/demo_sot_data/trackingnet/TRAIN_0"

    def read(rel: str) -> str:
        p = root / base / rel
        if p.is_file():
            return p.read_text()
        return subprocess.run(["git", "-C", str(root), "show", f"HEAD:{base}/{rel}"], check=True,
                              capture_output=True, text=True).stdout

    want = {"mmtracking": (67.524, 70.0, 50.0), "got10k": (68.667, None, None),
            "pytracking": (68.667, None, None)}
    for profile, (auc, npr, p20) in want.items():
        items = []
        for video in ("video-1", "video-2"):
            gt = _read_boxes(read(f"{video}/gt_for_eval.txt"))
            xyxy = _read_boxes(read(f"{video}/track_results.txt"))
            pred = np.c_[xyxy[:, :2], xyxy[:, 2:] - xyxy[:, :2]]
            items.append((M.score_sequence(pred, gt, profile=profile), ()))
        agg = M.aggregate(items).overall
        assert round(agg.msr * 100, 3) == auc
        if npr is not None:
            assert round(agg.pr * 100, 3) == npr and round(agg.precision20 * 100, 3) == p20


def test_frame_0_the_initialisation_is_left_out_of_both_rates():
    """QA passes 16b-c: 40 frames at 30 fps, the tracker every third frame, its initialisation at
    frame 0 taking 1090 ms (a model loaded on first use) and each call 45 ms, showed 10.5 (8.1)
    Hz; the protocol ran it at 10 Hz and its calls go at 22.2 Hz. vot_rt calls at frame 1 (its
    grace), then every fourth frame: 9.2 Hz where the calls go at 7.5 Hz. A got10k time file
    has no time at frame 0: its frame 1 is a call like the others."""
    ms = np.full(40, np.nan)
    ms[::3] = 45.0
    ms[0] = 1090.0
    f = M.block_frequencies({"tracker": ms}, 40, 30.0)["tracker"]
    assert f.scheduled_hz == pytest.approx(10.0) and f.wall_hz == pytest.approx(1000 / 45)
    vot = np.full(40, np.nan)
    vot[[0, 1, 5, 9, 13, 17, 21, 25, 29, 33, 37]] = 10.0
    assert M.block_frequencies({"tracker": vot}, 40, 30.0)["tracker"].scheduled_hz == pytest.approx(7.5)
    times = np.r_[1000.0, 50.0, np.full(80, 10.0)]             # pytracking: frame 0 timed
    for first in (1000.0, np.nan):                            # got10k: untimed (0, read as NaN)
        times[0] = first
        g = M.block_frequencies({"tracker": times}, 82, 30.0)["tracker"]
        assert g.wall_hz == pytest.approx(1000 * 81 / 850) and g.scheduled_hz == pytest.approx(30.0)
    for n in (1, 2):                                           # no interval from frame 1 on: unknown rate
        once = M.block_frequencies({"tracker": ms[:n]}, n, 30.0)["tracker"]
        assert np.isnan(once.scheduled_hz)


def test_rates_of_an_older_scores_json_still_read_and_add_up():
    """A scores.json of an older mata-eval has no `calls`: its wall rate is its starts over its
    time, and a sum with a newer entry keeps the older reading (no `calls` count to add)."""
    old = M.BlockFrequency.from_dict({"starts": 10, "camera_seconds": 1.0, "total_ms": 250.0})
    new = M.BlockFrequency(9, 0.9, 200.0, 10)
    assert old.wall_hz == pytest.approx(40.0) and new.wall_hz == pytest.approx(50.0)
    both = old + new
    assert both.scheduled_hz == pytest.approx(19 / 1.9) and both.wall_hz == pytest.approx(1000 * 19 / 450)
    assert M.BlockFrequency.from_dict(new.to_dict()) == new
