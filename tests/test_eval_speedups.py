"""Scoring in one process: several folders per `mata-eval eval`, numpy-parsed prediction files,
frame paths built only when a frame is read, `--version` without the packages."""

from __future__ import annotations

import json
import pickle
import shutil
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from mata_eval import __version__, cli
from mata_eval.core.sequence import FramePaths, FrameReadError
from mata_eval.data.datasets.annotations import DatasetError, frame_paths
from mata_eval.run.results import read_predictions


def _python_parse(text: str) -> np.ndarray:
    """Reference: the per-line parser (float() on every field)."""
    rows = [[float(p) for p in line.replace(",", " ").split()] for line in text.splitlines() if line.strip()]
    return np.array(rows, dtype=float).reshape(-1, 4)


def test_read_predictions_matches_float_on_every_separator(tmp_path):
    text = ("1,2,3,4\n"
            "0.1\t0.2\t1e3\t-7.25\n"
            "\n"
            "10 20  30 40\n"
            "5.000000000000001, 6.123456789012345, nan, 8\n"
            "1e-320,2,3,4\n")  # a subnormal: rounding must match float()
    f = tmp_path / "s.txt"
    f.write_text(text)
    got, want = read_predictions(f), _python_parse(text)
    assert got.shape == (5, 4)
    assert np.array_equal(got, want, equal_nan=True)
    assert got.view(np.uint64)[~np.isnan(got)].tolist() == want.view(np.uint64)[~np.isnan(want)].tolist()
    f.write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())   # a BOM and CRLF (QA pass 14)
    assert np.array_equal(read_predictions(f), want, equal_nan=True)


@pytest.mark.parametrize("bad, line", [("1,2,3,4\n1,2,3\n", 2), ("1,2,3,4\n\n1,2,x,4\n", 3),
                                       ("1,2,3,4,5\n", 1)])
def test_read_predictions_names_the_bad_line(tmp_path, bad, line):
    f = tmp_path / "s.txt"
    f.write_text(bad)
    with pytest.raises(ValueError, match=rf"s\.txt:{line}: expected 4 numbers"):
        read_predictions(f)


def test_empty_prediction_file(tmp_path):
    f = tmp_path / "s.txt"
    f.write_text("\n")
    assert read_predictions(f).shape == (0, 4)


def test_frame_paths_are_built_on_first_access_only(tmp_path):
    calls = []
    paths = FramePaths(lambda: calls.append(1) or ["a.jpg", "b.jpg"], 2)
    assert len(paths) == 2 and bool(paths) and calls == []
    assert paths[1] == "b.jpg" and list(paths) == ["a.jpg", "b.jpg"] and calls == [1]
    assert pickle.loads(pickle.dumps(paths)) == ("a.jpg", "b.jpg")
    with pytest.raises(FrameReadError, match="expected 3 frame paths, got 2"):
        FramePaths(lambda: ["a", "b"], 3)[0]


def test_dataset_frame_paths_list_or_name_the_frames(tmp_path):
    gt = tmp_path / "gt.txt"
    absent = frame_paths(tmp_path / "img", 3, "{:05d}.jpg", gt)
    assert list(absent) == [str(tmp_path / "img" / f"{k:05d}.jpg") for k in (1, 2, 3)]
    (tmp_path / "img").mkdir()
    for name in ("10.jpg", "2.jpg", "1.png", "notes.txt"):
        (tmp_path / "img" / name).write_bytes(b"")
    assert [p.rsplit("/", 1)[1] for p in frame_paths(tmp_path / "img", 3, "{:05d}.jpg", gt)] == \
        ["1.png", "2.jpg", "10.jpg"]
    with pytest.raises(DatasetError, match=r"gt\.txt: 4 ground-truth lines but 3 frames"):
        frame_paths(tmp_path / "img", 4, "{:05d}.jpg", gt)


def _rows(out: str) -> dict[str, list[str]]:
    return {line.split()[0]: line.split()[1:] for line in out.splitlines()[2:]
            if line.strip() and not line.startswith("- ")}  # "- SR: ..." lines: the table's legend


def test_eval_scores_several_folders_in_one_process(shared_data, tmp_path, capsys):
    """DTB70, pysot-toolkit profile: SiamAPN++'s published AUC 0.594 and precision 0.789 in the
    row of a two-folder call, and SiamAPN's row identical to a call of its own."""
    with zipfile.ZipFile(shared_data / "results" / "DTB70.zip") as z:
        z.extractall(tmp_path, [n for n in z.namelist()
                                if n.startswith(("DTB70/SiamAPN++/", "DTB70/SiamAPN/"))])
    ann = shared_data / "annotations" / "DTB70"
    common = ["--dataset", "dtb70", "--root", str(ann), "--set", f"annotations={ann}", "--profile", "pysot-toolkit"]
    both = [str(tmp_path / "DTB70" / t) for t in ("SiamAPN++", "SiamAPN")]
    assert cli.main(["eval", *both, *common]) == 0
    rows = _rows(capsys.readouterr().out)
    assert set(rows) == {"SiamAPN++", "SiamAPN"}
    header = ["Seqs", "SR", "MSR", "PR", "P@20"]
    plus = dict(zip(header, rows["SiamAPN++"]))
    assert plus["Seqs"] == "70" and plus["MSR"] == "59.4" and plus["P@20"] == "78.9"
    assert cli.main(["eval", both[1], *common]) == 0
    assert _rows(capsys.readouterr().out)["SiamAPN"] == rows["SiamAPN"]
    assert cli.main(["eval", both[1], *common, "--layout", "got10k"]) == 1   # (QA pass 15b: not said why)
    assert (f"{both[1]}: --layout got10k found no results; the folder holds the pysot layout"
            in capsys.readouterr().out)
    assert cli.main(["eval", *both, *common, "--name", "x"]) == 2
    assert "--name takes one RESULTS_DIR" in capsys.readouterr().err
    # --output with several folders: OUTPUT/<folder name>/scores.json each, with the dataset's
    # name, so that `report` of them is the same table (QA pass 15b: refused; the dataset was null)
    assert cli.main(["eval", *both, *common, "--output", str(tmp_path / "o")]) == 0
    capsys.readouterr()
    saved = [tmp_path / "o" / t for t in ("SiamAPN++", "SiamAPN")]
    assert [json.loads((s / "scores.json").read_text())["meta"]["dataset"] for s in saved] == ["dtb70", "dtb70"]
    assert cli.main(["report", *map(str, saved)]) == 0
    out = capsys.readouterr().out
    assert _rows(out) == rows and "different datasets" not in out
    # the same folder twice is scored once (QA pass 15b: two rows, "(default, 1)" and "(default, 2)")
    assert cli.main(["eval", both[1], both[1] + "/", *common]) == 0
    first, out = capsys.readouterr().out.split("\n", 1)
    assert first == f"{both[1]} is given more than once: scored once" and list(_rows(out)) == ["SiamAPN"]
    # a folder that cannot be scored in the middle: said, and the others scored (QA pass: the
    # call stopped there, and the last folder was never scored)
    bad = tmp_path / "DTB70" / "Empty"
    bad.mkdir()
    assert cli.main(["eval", both[0], str(bad), both[1], *common]) == 2
    out, err = capsys.readouterr()
    assert set(_rows(out)) == {"SiamAPN++", "SiamAPN"} and f"{bad}: no results found" in err
    # a file that cannot be scored: its sequence is named and counted as failed, and the folder's
    # other sequences are scored (QA pass: the folder was not scored at all)
    broken = tmp_path / "DTB70" / "Broken"
    shutil.copytree(both[1], broken)
    (broken / "Animal1.txt").write_text("1,2,3\n")
    assert cli.main(["eval", str(broken), *common]) == 1        # as `run` (QA pass 15b: 0)
    out = capsys.readouterr().out
    assert f"cannot score Broken/Animal1: {broken / 'Animal1.txt'}:1: expected 4 numbers" in out
    assert _rows(out)["Broken"][0] == "69" and _rows(out)["Broken"][-1] == "1"   # Seqs, Failed
    # a profile that cuts a short file says so (QA pass 15b: got10k scored 20 of 149 frames silently)
    (broken / "Animal1.txt").write_text("".join(f"{10 + k},10,20,20\n" for k in range(20)))
    common[-1] = "got10k"
    assert cli.main(["eval", str(broken), *common]) == 0
    n = len(np.loadtxt(ann / "Animal1.txt", delimiter=","))
    assert (f"1 result file(s) have another length than their sequence, scored over the shorter of the two "
            f"as the got10k profile does: Animal1 (20 lines, {n} frames)") in capsys.readouterr().out


def test_vot_reset_based_output_is_named_as_such(tmp_path):
    """QA pass 15b: the VOT toolkit's baseline output (1 = initialised, 2 = failed, 0 = skipped)
    gave "expected 4 numbers" only."""
    f = tmp_path / "bag_001.txt"
    f.write_text("1\n10,10,20,20\n2\n0\n")
    with pytest.raises(ValueError, match=r"bag_001.txt:1: expected 4 numbers x,y,w,h, got '1' \(.*VOT toolkit's reset"):
        read_predictions(f)
    f.write_text("10,10,20,20\n7\n")
    with pytest.raises(ValueError) as err:
        read_predictions(f)
    assert "VOT" not in str(err.value)


def test_version_answers_without_importing_the_packages():
    code = ("import sys; from mata_eval import cli; rc = cli.main(['--version']); "
            "print(sorted(m for m in sys.modules if m.startswith('mata_eval.') or m in ('numpy', 'cv2')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[0] == f"mata-eval {__version__}"
    # no numpy; mata_eval.run is its package __init__ only (imported to make `mata_eval.run(...)` callable)
    assert eval(out.splitlines()[1]) == ["mata_eval.cli", "mata_eval.core", "mata_eval.core.errors", "mata_eval.run"]


def test_ground_truth_parser_matches_float_and_names_bad_lines(tmp_path):
    from mata_eval.data.datasets.annotations import AnnotationError, read_boxes

    f = tmp_path / "gt.txt"
    f.write_text("1,2,3,4\n5;6;7;8\n9\t10 11,12\nNaN,NaN,NaN,NaN\n0.1,0.2,0.30000000000000004,1e-320\n\n")
    got = read_boxes(f)
    want = np.array([[1, 2, 3, 4], [5, 6, 7, 8], [9, 10, 11, 12], [np.nan] * 4, [0.1, 0.2, 0.30000000000000004, 1e-320]])
    assert got.tobytes() == want.tobytes()
    f.write_text("1,2,3,4\n  \n5,6,7,8\n")
    with pytest.raises(AnnotationError, match="2.*blank line inside the file"):
        read_boxes(f)
    f.write_text("1,2,3,4\n5,6,7\n")
    with pytest.raises(AnnotationError, match="2.*got 3 value"):
        read_boxes(f)
