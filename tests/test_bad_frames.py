"""Corrupted frames are never scored silently: a truncated JPEG, an undecodable file or a frame
whose size changes inside a sequence fails the sequence naming the frame, or, with
``on_bad_frame: skip``, the frame is excluded from scoring and counted."""

from __future__ import annotations

import json
import re
import shutil
import textwrap

import cv2
import numpy as np
import pytest

from mata_eval.run.config import load_experiment
from mata_eval.run.runner import run_experiment
from mata_eval.core.sequence import FrameReadError, read_image

N = 6


@pytest.fixture
def clip(shared_data, tmp_path):
    """The first 6 frames of a real 30 fps sequence in the generic folder layout."""
    src = shared_data / "sequences" / "aerial30" / "MountainBike6"
    dst = tmp_path / "data" / "bike"
    (dst / "img").mkdir(parents=True)
    frames = sorted((src / "img").glob("*.jpg"))[:N]
    for f in frames:
        shutil.copy(f, dst / "img" / f.name)
    gt = (src / "groundtruth_rect.txt").read_text().splitlines()[:N]
    (dst / "groundtruth_rect.txt").write_text("\n".join(gt) + "\n")
    return dst


def _run(tmp_path, extra=""):
    p = tmp_path / "exp.yaml"
    p.write_text(textwrap.dedent(f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: folder, root: {tmp_path / 'data'}}}
        tracker: {{name: kcf}}
        """) + extra)
    logs = []
    outcomes = run_experiment(load_experiment(p), jobs=1, progress=False, log=logs.append)
    assert len(outcomes) == 1
    return outcomes[0], logs


def _truncate(path, keep=0.6):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def test_read_image_refuses_truncated_and_garbage_files(clip, tmp_path):
    good = sorted((clip / "img").glob("*.jpg"))[0]
    reference = cv2.imread(str(good), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(read_image(str(good)), reference)  # same decoder, same pixels
    for keep in (0.3, 0.99):
        bad = tmp_path / f"cut{keep}.jpg"
        bad.write_bytes(good.read_bytes()[: int(good.stat().st_size * keep)])
        with pytest.raises(FrameReadError, match="truncated"):
            read_image(str(bad))
    junk = tmp_path / "junk.jpg"
    junk.write_bytes(b"\xff\xd8 not an image \xff\xd9")
    with pytest.raises(FrameReadError, match="cannot decode"):
        read_image(str(junk))
    png = tmp_path / "cut.png"
    png.write_bytes(cv2.imencode(".png", reference)[1].tobytes()[:50_000])
    with pytest.raises(FrameReadError):
        read_image(str(png))


def test_a_truncated_frame_fails_the_sequence_naming_the_frame(clip, tmp_path):
    _truncate(sorted((clip / "img").glob("*.jpg"))[3])
    outcome, _ = _run(tmp_path)
    assert outcome.status == "failed"
    assert "frame 3" in outcome.reason and "truncated" in outcome.reason
    assert not (tmp_path / "out" / "exp" / "bike.txt").exists()


def test_a_frame_of_another_size_fails_the_sequence(clip, tmp_path):
    f = sorted((clip / "img").glob("*.jpg"))[4]
    img = cv2.imread(str(f))
    cv2.imwrite(str(f), cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2)))
    outcome, _ = _run(tmp_path)
    assert outcome.status == "failed"
    assert "frame 4" in outcome.reason
    assert f"{img.shape[1] // 2}x{img.shape[0] // 2}" in outcome.reason
    assert f"{img.shape[1]}x{img.shape[0]}" in outcome.reason
    assert str(f) in outcome.reason                    # the file, not only its index (QA pass)


@pytest.mark.parametrize("frame, got", [
    (None, "NoneType"), (np.zeros((8, 8), np.uint8), "uint8 array of shape (8, 8)"),
    (np.zeros((8, 8, 4), np.uint8), "uint8 array of shape (8, 8, 4)"),
    (np.zeros((8, 8, 3), np.float32), "float32 array of shape (8, 8, 3)")])
def test_a_loader_that_gives_no_bgr_image_is_named(frame, got):
    """A sequence's own loader (the Python API, a plugin) that gives None, grey, BGRA or float
    frames: a FrameReadError naming the frame and what is expected, where the blocks failed with
    a numpy broadcast error, an AttributeError, or silently ran on (QA pass)."""
    from mata_eval.core.sequence import Sequence

    seq = Sequence("mine", np.tile([1.0, 1.0, 4.0, 4.0], (3, 1)), 30.0, loader=lambda k: frame)
    with pytest.raises(FrameReadError, match=re.escape(f"frame 2 of sequence 'mine': its loader gave a {got}; "
                                                       "expected an (H, W, 3) uint8 BGR image")):
        seq.image(2)


def test_skip_excludes_the_bad_frame_from_scoring_and_counts_it(clip, tmp_path):
    _truncate(sorted((clip / "img").glob("*.jpg"))[3])
    outcome, logs = _run(tmp_path, "on_bad_frame: skip\n")
    assert outcome.status == "done"
    run = tmp_path / "out" / "exp"
    rows = (run / "bike.frames.csv").read_text().splitlines()
    header = rows[0].split(",")
    scored = [int(r.split(",")[header.index("scored")]) for r in rows[1:]]
    assert scored == [1, 1, 1, 0, 1, 1]
    assert outcome.bad_frames == (3,)
    assert any("1 bad frame" in line and "bike" in line for line in logs)
    bad = json.loads((run / "bike.bad_frames.json").read_text())
    assert list(bad["frames"]) == ["3"]


def test_the_report_says_how_many_frames_were_skipped(clip, tmp_path, capsys):
    """The table's "Excl. frames" counts frames without ground truth; frames skipped as
    unreadable are named under the table instead, for ``eval`` and ``report`` alike (QA pass:
    the count appeared only in the run's log line)."""
    from mata_eval import cli

    _truncate(sorted((clip / "img").glob("*.jpg"))[3])
    _run(tmp_path, "on_bad_frame: skip\n")
    run = tmp_path / "out" / "exp"
    assert cli.main(["report", str(run)]) == 0
    line = "1 unreadable frame(s) skipped and not scored (on_bad_frame: skip): bike (1)"
    assert line in capsys.readouterr().out
    assert cli.main(["eval", str(run), "--dataset", "folder", "--root", str(tmp_path / "data")]) == 0
    assert line in capsys.readouterr().out
