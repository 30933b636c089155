"""Run-folder files: atomic writes, the pysot-toolkit prediction layout, failures."""

import numpy as np
import pytest

from mata_eval.run import results


def test_predictions_round_trip_in_pysot_layout(tmp_path):
    boxes = np.array([[1.5, 2.25, 30.0, 40.125], [np.nan, np.nan, np.nan, np.nan]])
    results.write_sequence(tmp_path, "car1", boxes, "frame,scored\n", "block,event,frame,t\n")
    text = (tmp_path / "car1.txt").read_text().splitlines()
    assert text[0] == "1.5000,2.2500,30.0000,40.1250"  # comma separated x,y,w,h floats
    back = results.read_predictions(tmp_path / "car1.txt")
    np.testing.assert_array_equal(np.isnan(back), np.isnan(boxes))
    np.testing.assert_allclose(back[0], boxes[0])
    assert results.is_finished(tmp_path, "car1")


def test_foreign_layouts_read_tab_and_space(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("1\t2\t3\t4\n5 6 7 8\n")
    np.testing.assert_array_equal(results.read_predictions(p), [[1, 2, 3, 4], [5, 6, 7, 8]])


def test_bad_prediction_line_names_file_and_line(tmp_path):
    p = tmp_path / "b.txt"
    p.write_text("1,2,3,4\n1,2,x,4\n")
    with pytest.raises(ValueError, match=r"b\.txt:2: expected 4 numbers"):
        results.read_predictions(p)


def test_atomic_write_leaves_old_file_when_interrupted(tmp_path, monkeypatch):
    target = tmp_path / "car1.txt"
    results.atomic_write_text(target, "old\n")

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(results.os, "replace", boom)
    with pytest.raises(KeyboardInterrupt):
        results.atomic_write_text(target, "new\n")
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["car1.txt"]  # no temp file left behind


def test_failure_is_recorded_and_cleared_by_success(tmp_path):
    results.write_failure(tmp_path, "bike2", "FrameReadError: cannot read frame 3", "tb")
    assert results.read_failures(tmp_path) == {"bike2": "FrameReadError: cannot read frame 3"}
    results.write_sequence(tmp_path, "bike2", np.zeros((1, 4)), "", "")
    assert results.read_failures(tmp_path) == {}
