"""The perfect-tracker experiment (issue 15): what a protocol's rate and latency alone cost.

A tracker that returns the ground-truth box of the frame it is given is run through the same
scheduler as every method (:func:`mata_eval.scheduler.run_sequence`) under a protocol, e.g. EOP
with the tracker at 10 Hz and a one-period latency (paper section 3.1), and scored with the same
metrics. Its NT2F is then the fraction of a sequence it survives on held, late boxes alone: an
upper bound for any tracker under that protocol, and a measure of how fast the targets of a
dataset move relative to their size. Where the target is absent (NaN ground truth), the perfect
tracker keeps its last box: it cannot see what is not there.
"""

from __future__ import annotations

import dataclasses
from typing import Iterable

import numpy as np

from ..core.sequence import Sequence
from ..core.types import Box, TrackerOutput
from ..run.scheduler import ProtocolPreset, SequenceRun, run_sequence
from .metrics import SequenceScores, score_sequence


class PerfectTracker:
    """Returns the ground-truth box of the frame it is handed (the last valid one where the
    ground truth is NaN). The "image" it is handed is a 1x1 BGR pixel holding the frame index
    (:func:`_frame_index`)."""

    def __init__(self, groundtruth: np.ndarray):
        self.groundtruth = np.asarray(groundtruth, dtype=float)
        self.last = Box.from_array(self.groundtruth[0])

    def initialize(self, frame_index: np.ndarray, box: Box) -> None:
        self.last = box

    def track(self, frame_index: np.ndarray, prior: object = None) -> TrackerOutput:
        b, g, r = (int(v) for v in frame_index[0, 0])
        box = Box.from_array(self.groundtruth[b + 256 * g + 65536 * r])
        if box.is_valid:
            self.last = box
        return TrackerOutput(self.last, 1.0)


def _frame_index(k: int) -> np.ndarray:
    """Frame ``k`` as the image of a 1x1 BGR frame: its index in base 256 (up to 16.7 M frames)."""
    return np.array([[[k & 255, (k >> 8) & 255, (k >> 16) & 255]]], np.uint8)


def oracle_run(sequence: Sequence, protocol: ProtocolPreset) -> SequenceRun:
    """The perfect tracker on ``sequence`` under ``protocol`` (no egomotion, no estimator: the
    tracker's output is held between its publishes). No image is read: the sequence's frames
    are replaced by 1x1 images holding their indices."""
    indexed = dataclasses.replace(sequence, loader=_frame_index)
    return run_sequence(indexed, PerfectTracker(sequence.groundtruth), None, None, protocol,
                        np.random.default_rng(0), feedback=False)


def oracle_scores(sequences: Iterable[Sequence], protocol: ProtocolPreset,
                  profile: str = "default") -> list[SequenceScores]:
    """Scores of the perfect tracker on each sequence (metric ``profile``)."""
    out = []
    for seq in sequences:
        run = oracle_run(seq, protocol)
        out.append(score_sequence(run.boxes, seq.groundtruth, profile=profile, scored=run.scored,
                                  annotated=seq.annotated))
    return out
