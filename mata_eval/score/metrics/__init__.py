"""Tracking metrics (paper section 3.3; DESIGN.md "Metrics"; ``docs/metrics.md``).

- :mod:`.measures`: per-frame IoU / centre error, one sequence's SR, MSR, PR, P@20 and NT2F;
- :mod:`.aggregate`: means per dataset, per attribute and per challenge group;
- :mod:`.frequencies`: how often each block ran.

The profile table that reproduces pysot, pysot-toolkit, got10k, pytracking and mmtracking is
plain data in :mod:`mata_eval.core.metric_profiles` (the experiment file names a profile).
"""

from ...core.metric_profiles import (GOT10K_IOU_GRID, NORM_GRID, P20_INDEX, PIXEL_GRID, PROFILES,
                                     PYSOT_IOU_GRID, PYTRACKING_IOU_GRID, SR_INDEX, Profile, get_profile)
from .aggregate import DEFAULT_GROUPS, METRIC_NAMES, Aggregate, Summary, aggregate, summarize
from .frequencies import BlockFrequency, block_frequencies, combine_frequencies
from .measures import (SequenceScores, centers, first_failure, iou, iou_pixel_inclusive, nt2f,
                       prepare_predictions, score_sequence, valid_ground_truth)

__all__ = ["DEFAULT_GROUPS", "GOT10K_IOU_GRID", "METRIC_NAMES", "NORM_GRID", "P20_INDEX", "PIXEL_GRID",
           "PROFILES", "PYSOT_IOU_GRID", "PYTRACKING_IOU_GRID", "SR_INDEX", "Aggregate", "BlockFrequency",
           "Profile", "SequenceScores", "Summary", "aggregate", "block_frequencies", "centers",
           "combine_frequencies", "first_failure", "get_profile", "iou", "iou_pixel_inclusive", "nt2f",
           "prepare_predictions", "score_sequence", "summarize", "valid_ground_truth"]
