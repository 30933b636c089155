"""Motion statistics and the perfect-tracker oracle (issue 15): hand-computed cases, the EOP
timeline worked out by hand, and the UAV123 figures quoted in the issue."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mata_eval.core.registry import load_registry
from mata_eval.core.sequence import Sequence
from mata_eval.score.metrics import summarize
from mata_eval.score.motion_stats import (camera_motion, camera_rates, on_annotation_grid, similarity_parts,
                                          target_motion)
from mata_eval.score.oracle import oracle_run, oracle_scores


def moving_box(n: int, dx: float, size: float = 10.0) -> np.ndarray:
    """A size x size box whose left edge moves dx px per frame."""
    k = np.arange(n, dtype=float)
    return np.stack([dx * k, np.zeros(n), np.full(n, size), np.full(n, size)], axis=1)


def eop(hz: float):
    cls = load_registry().get("protocol", "eop").cls
    return cls(cls.Params(tracker_hz=hz))


# --- target motion ---------------------------------------------------------------------------

def test_target_motion_of_a_box_moving_at_constant_speed():
    """10 x 10 box, 2 px/frame: shift/size = 0.2 per frame; IoU after 1 frame = 80/120, after 3
    frames = 40/160; no scale change. Frame 5 NaN removes the pairs it belongs to."""
    gt = moving_box(20, 2.0)
    gt[5] = np.nan
    m = target_motion([gt])
    one, three, ten = m.at(1), m.at(3), m.at(10)
    assert (one.n_pairs, three.n_pairs, ten.n_pairs) == (19 - 2, 17 - 2, 10 - 1)
    assert one.displacement_median == pytest.approx(0.2) and one.displacement_p90 == pytest.approx(0.2)
    assert three.displacement_median == pytest.approx(0.6) and ten.displacement_median == pytest.approx(2.0)
    assert one.scale_median == 0 and ten.scale_p90 == 0
    assert one.iou_below_half == 0.0 and three.iou_below_half == 1.0
    with pytest.raises(KeyError, match="lag 2"):
        m.at(2)


def test_target_motion_scale_and_pooling():
    """A box growing by 10 % per frame about a fixed centre: |log size ratio| = lag * ln 1.1,
    shift 0. Pooled with a still box (scale 0), the 90th percentile is the growing one's."""
    k = np.arange(30, dtype=float)
    side = 20 * 1.1 ** k
    grow = np.stack([100 - side / 2, 100 - side / 2, side, side], axis=1)
    still = np.tile([0.0, 0.0, 5.0, 5.0], (30, 1))
    m = target_motion([grow, still], lags=(3,))
    assert m.n_sequences == 2
    assert m.at(3).displacement_p90 == pytest.approx(0.0, abs=1e-12)
    assert m.at(3).scale_p90 == pytest.approx(3 * math.log(1.1))
    assert m.at(3).scale_median == pytest.approx(1.5 * math.log(1.1))  # half the pairs grow, half not


def test_on_annotation_grid_rounds_x_y_w_h_to_whole_pixels_of_the_annotated_frame():
    """At 1280 wide: 10.4 -> 10, 5.5001 -> 6, 20.3 -> 20, 7.2 -> 7 (each of x, y, w, h, as
    UAV123's integer files). At 320 wide the grid is a quarter pixel: 2.6 -> 2.5, 5.1 -> 5.0,
    1.13 -> 1.25. NaN rows stay NaN; a box that grows by less than half a grid pixel keeps
    exactly the same size (the zero scale changes of integer annotations)."""
    got = on_annotation_grid(np.array([[10.4, 5.5001, 20.3, 7.2], [np.nan] * 4]), 1280)
    np.testing.assert_array_equal(got[0], [10.0, 6.0, 20.0, 7.0])
    assert np.all(np.isnan(got[1]))
    np.testing.assert_array_equal(on_annotation_grid(np.array([2.6, 1.13, 5.1, 2.0]), 320), [[2.5, 1.25, 5.0, 2.0]])
    slow = np.array([[100.0 + 0.3 * k, 50.0, 30.0 + 0.04 * k, 20.0] for k in range(10)])
    assert target_motion([on_annotation_grid(slow, 1280)]).at(3).scale_median == 0.0
    assert target_motion([slow]).at(3).scale_median > 0.0


# --- camera motion ---------------------------------------------------------------------------

def similarity_about(c: np.ndarray, t: np.ndarray, angle: float, scale: float) -> np.ndarray:
    """x -> c + t + scale R(angle) (x - c)."""
    ca, sa = math.cos(angle), math.sin(angle)
    A = scale * np.array([[ca, -sa], [sa, ca]])
    H = np.eye(3)
    H[:2, :2] = A
    H[:2, 2] = c + t - A @ c
    return H


def test_similarity_parts_recovers_a_similarity_about_the_centre():
    c = np.array([64.0, 36.0])
    H = similarity_about(c, np.array([3.0, -4.0]), math.radians(2.0), 1.05)
    shift, rot, log_scale = similarity_parts(H, 128, 72)
    np.testing.assert_allclose(shift, [3.0, -4.0], atol=1e-12)
    assert rot == pytest.approx(math.radians(2.0)) and log_scale == pytest.approx(math.log(1.05))
    # a projective term does not move the centre's linearisation away from the similarity's
    P = np.eye(3)
    P[2, :2] = [1e-6, 0.0]
    P[2, 2] = 1 - 1e-6 * c[0]  # keeps the centre fixed
    shift, rot, _ = similarity_parts(P @ H, 128, 72)
    assert np.linalg.norm(shift - [3.0, -4.0]) < 0.01 and rot == pytest.approx(math.radians(2.0), abs=1e-4)


def test_camera_rates_per_second_with_jerk_and_gaps():
    """Translations of 5, 5, 8 px/frame at 100 px wide, 30 fps: 1.5, 1.5, 2.4 widths/s; jerk
    (change of velocity per frame, times fps) 0 then 0.9 * 30; a failed estimate (None) is
    skipped and breaks the jerk chain."""
    T = lambda dx: np.array([[1, 0, dx], [0, 1, 0], [0, 0, 1.0]])  # noqa: E731
    r = camera_rates([T(5), T(5), T(8), None, T(1)], 100, 50, 30.0)
    np.testing.assert_allclose(r[:, 0], [1.5, 1.5, 2.4, 0.3])
    np.testing.assert_allclose(r[:, 1:3], 0.0, atol=1e-12)
    assert math.isnan(r[0, 3]) and r[1, 3] == pytest.approx(0.0) and r[2, 3] == pytest.approx(27.0)
    assert math.isnan(r[3, 3])
    c = camera_motion([r], 30.0)
    assert c.n_frames == 4 and c.translation_median == pytest.approx(1.5) and c.jerk_median == pytest.approx(13.5)


# --- the oracle ------------------------------------------------------------------------------

def test_oracle_follows_the_hand_computed_eop_timeline():
    """EOP, tracker at 10 Hz on 30 fps with a one-period latency: the tracker initialises at
    frame 0 (nothing published: the initial box is held), processes frames 3, 6, 9, ... and each
    output is visible 3 frames later, so frames 0-5 show frame 0's box, 6-8 frame 3's, 9-11
    frame 6's. A 10 px box moving 2 px/frame: at frame 5 the held box is 10 px behind, IoU = 0,
    the first failure: NT2F = 5 / 30. At 30 Hz with one frame of latency the held box is one
    frame (2 px) old: never fails, NT2F = 1."""
    seq = Sequence("hand", moving_box(30, 2.0), fps=30.0)
    run = oracle_run(seq, eop(10))
    np.testing.assert_array_equal(run.source_frame[:12], [0, 0, 0, 0, 0, 0, 3, 3, 3, 6, 6, 6])
    np.testing.assert_allclose(run.boxes[7], seq.groundtruth[3])
    (s10,) = oracle_scores([seq], eop(10))
    assert s10.failure_frame == 5 and s10.nt2f == pytest.approx(5 / 30)
    run30 = oracle_run(seq, eop(30))
    np.testing.assert_array_equal(run30.source_frame[:4], [0, 0, 1, 2])
    (s30,) = oracle_scores([seq], eop(30))
    assert s30.nt2f == 1.0


def test_oracle_holds_the_last_box_while_the_target_is_absent():
    """Frames 10-14 NaN (the target is out of view) and it comes back 50 px further: at 30 Hz
    frame 15 shows the last valid box (frame 9's), IoU 0: failure at frame 15 of 30 (eq. nt2f),
    at the 11th valid frame of 25 when only valid frames count (profile nt2f-valid)."""
    gt = moving_box(30, 0.5)
    gt[10:15] = np.nan
    gt[15:, 0] += 50
    seq = Sequence("gap", gt, fps=30.0)
    (s,) = oracle_scores([seq], eop(30))
    assert s.failure_frame == 15 and s.nt2f == pytest.approx(15 / 30)
    (s,) = oracle_scores([seq], eop(30), profile="nt2f-valid")
    assert s.nt2f == pytest.approx(10 / 25)


def test_uav123_figures_of_the_issue(shared_data):
    """Issue 15 quotes, on UAV123's 123 sequences: oracle NT2F 56.0 at 10 Hz (84.8 at 30 Hz:
    benchmarks/oracle.py), median 3-frame shift 0.083 of the target size, 15.3 % of 3-frame pairs
    with IoU < 0.5. Its NT2F counted valid frames only (profile nt2f-valid); eq. nt2f, which
    counts every frame (the default profile), gives 56.2."""
    from mata_eval.data.datasets.uav123 import UAV123

    ann = shared_data / "annotations" / "UAV123"
    seqs = UAV123(UAV123.Params(root=str(ann), annotations=str(ann))).sequences()
    assert len(seqs) == 123
    scores = oracle_scores(seqs, eop(10), profile="nt2f-valid")
    assert round(100 * summarize(scores).nt2f, 1) == 56.0
    m = target_motion(s.groundtruth for s in seqs).at(3)
    assert round(m.displacement_median, 3) == 0.083 and round(100 * m.iou_below_half, 1) == 15.3
