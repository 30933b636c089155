"""benchmarks/embedded_profiles.py: which tracker calls of a vot_rt run make the emulated
device's timing profile (hand-written frames.csv files)."""

from __future__ import annotations

import numpy as np

from conftest import benchmark


def _module():
    return benchmark("embedded_profiles")


def test_tracker_wall_times_leave_out_the_initialisation_and_frames_without_a_call(tmp_path):
    """Two sequences: frame 0 (initialisation) and frames where the tracker did not run (empty or
    nan) are left out; what remains is 164, 4, 6 (seq a) and 150, 5 ms (seq b), in seconds. With
    vot_rt's grace (x30 at 30 fps: a call over 1.1 ms is slower than a frame), each sequence's
    first such call is left out as the protocol forgave it: seq a's initialisation (240.5 ms)
    took it, so its 164 ms call stays; seq b's 0.5 ms initialisation did not, so its 150 ms goes."""
    head = "frame,scored,confidence,tracker_ms,source_frame\n"
    (tmp_path / "a.frames.csv").write_text(head + "0,1,nan,240.5,0\n1,1,nan,164.0,0\n2,1,0.9,4.0,1\n3,1,,,1\n"
                                           "4,1,0.8,6.0,3\n")
    (tmp_path / "b.frames.csv").write_text(head + "0,1,nan,0.5,0\n1,1,0.7,150.0,0\n2,1,0.7,5.0,0\n")
    got = _module().tracker_wall_s(tmp_path)
    np.testing.assert_allclose(np.sort(got), [0.004, 0.005, 0.006, 0.150, 0.164])
    graced = _module().tracker_wall_s(tmp_path, scale=30.0, grace=1, interval_s=1 / 30)
    np.testing.assert_allclose(np.sort(graced), [0.004, 0.005, 0.006, 0.164])
    assert _module().tracker_wall_s(tmp_path / "missing").size == 0

