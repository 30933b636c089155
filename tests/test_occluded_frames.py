"""Metrics on occluded frames (paper 3.2): only the frames an augmented occluder covers count."""

import numpy as np

from mata_eval.score import evaluate
from mata_eval.core.sequence import Sequence


def test_scores_on_the_covered_frames_only():
    gt = np.tile([10.0, 10.0, 20.0, 20.0], (5, 1))
    pred = gt.copy()
    pred[3] = [100.0, 100.0, 20.0, 20.0]   # lost on the fully covered frame
    pred[4] = [100.0, 100.0, 20.0, 20.0]   # and after it (not covered: not counted here)
    seq = Sequence("s", gt, meta={"occlusion": np.array([0.0, 0.0, 0.5, 1.0, 0.0])})
    res = evaluate.SequenceResult(pred)
    occ = evaluate.occluded_frame_scores(res, seq, "default")
    assert occ.n_scored == 2
    assert occ.sr == 0.5                  # frame 2 (IoU 1) succeeds, frame 3 (IoU 0) fails
    per_seq, _, summary, _, _ = evaluate.score_results({"s": res}, [seq])
    assert per_seq["s"].sr == 3 / 5       # all frames
    assert summary.occluded_frames.sr == 0.5 and summary.occluded_frames.n_scored == 2


def test_no_occlusion_metadata_means_no_occluded_scores():
    gt = np.tile([10.0, 10.0, 20.0, 20.0], (3, 1))
    res = evaluate.SequenceResult(gt.copy())
    assert evaluate.occluded_frame_scores(res, Sequence("s", gt), "default") is None
    assert evaluate.score_results({"s": res}, [Sequence("s", gt)])[2].occluded_frames is None
