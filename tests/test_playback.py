"""`mata-eval play` on real footage: the video opens with the right frame count and size, the
ground truth is drawn where it is, and a MATA run records its tracker's box and search region."""

from __future__ import annotations

import csv
import textwrap

import cv2
import numpy as np
import pytest

import mata_eval as me
from mata_eval.cli import main
from mata_eval.report.playback import GT_COLOUR, RunTrack, draw_frame, read_run_track, run_colours, sequence_of_run

SEQ = "wakeboard7"  # UAV123_10fps, 67 frames of 1280x720, a small target on water


@pytest.fixture(scope="module")
def runs(shared_data, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("play")
    exp = tmp / "exp.yaml"
    exp.write_text(textwrap.dedent(f"""
        output: {tmp / 'out'}
        dataset: {{name: folder, root: {shared_data / 'sequences' / 'uav123_10fps'}, fps: 10, sequences: [{SEQ}]}}
        occlusion: {{n_events: 1}}
        tracker: {{name: kcf}}
        egomotion: {{name: grid_lk}}
        estimator: {{name: homography_ekf}}
        matrix:
          mata:
            baseline: {{egomotion: null, estimator: null}}
            mata: {{}}
        """))
    me.run(exp, jobs=1, progress=False)
    return tmp, [tmp / "out" / "baseline", tmp / "out" / "mata"]


def test_video_has_the_frames_asked_as_drawn(runs):
    tmp, dirs = runs
    out = tmp / "play.mp4"
    assert main(["play", *map(str, dirs), "--sequence", SEQ, "--out", str(out), "--frames", "10:40"]) == 0
    cap = cv2.VideoCapture(str(out))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    assert len(frames) == 30 and cap.get(cv2.CAP_PROP_FRAME_COUNT) == 30
    seq = sequence_of_run(dirs[0], SEQ)
    tracks = [read_run_track(d, SEQ, len(seq)) for d in dirs]
    for i in (0, 29):  # what the file holds is what draw_frame drew (up to the codec's loss)
        k = 10 + i
        drawn = draw_frame(seq.image(k), k, seq.groundtruth, tracks, run_colours(2),
                           [e.outline(k) for e in seq.meta["occlusion_events"] if e.active(k)])
        assert frames[i].shape == drawn.shape and frames[0].shape[1] == 1280
        assert np.abs(frames[i].astype(float) - drawn).mean() < 6.0


def test_boxes_are_drawn_where_they_are(shared_data):
    """Ground truth in green on its edges, a run's box and its dashed search region in the
    run's colour on theirs (exact pixels: no codec here)."""
    img = cv2.imread(str(shared_data / "sequences" / "uav123_10fps" / SEQ / "img" / "000001.jpg"))
    gt = np.array([[100.0, 100.0, 60.0, 40.0]])
    colour = run_colours(1)[0]
    track = RunTrack("r", np.array([[400.0, 300.0, 50.0, 50.0]]), np.zeros(1, int), (frozenset({"tracker"}),),
                     np.array([[400.0, 300.0, 50.0, 50.0]]), np.array([[350.0, 250.0, 150.0, 150.0]]), False)
    out = draw_frame(img, 0, gt, [track], [colour])
    assert tuple(out[100, 130]) == GT_COLOUR and tuple(out[140, 130]) == GT_COLOUR
    assert tuple(out[300, 425]) == colour and tuple(out[350, 425]) == colour
    dashed = [tuple(out[250, x]) == colour for x in range(352, 498)]
    assert 0.3 < np.mean(dashed) < 0.7  # every other dash
    assert out.shape[0] > img.shape[0] and np.array_equal(out[:, :90][200:290], img[:, :90][200:290])


def test_captions_wrap_on_a_small_frame():
    """On a 320 px frame the legend and a run's line wrap onto more lines instead of running off
    the right edge (QA pass: cut off); on a 1280 px frame each is one line."""
    track = RunTrack("a-run-with-a-long-name", np.array([[10.0, 10.0, 20.0, 20.0]]), np.zeros(1, int),
                     (frozenset({"tracker", "egomotion", "estimator"}),), None, None, True)
    heights = {}
    for width in (320, 1280):
        img = np.full((240, width, 3), 90, np.uint8)
        out = draw_frame(img, 0, np.array([[5.0, 5.0, 30.0, 30.0]]), [track], run_colours(1))
        strip = out[240:]
        heights[width] = strip.shape[0]
        lit = np.flatnonzero((strip > 0).any(axis=(0, 2)))
        assert lit.max() < width - 4, f"caption reaches the right edge at {width} px"
    rows = {w: (h - int(40 * s) // 3) / int(40 * s) for (w, h), s in zip(heights.items(), (0.45, 0.8))}
    assert rows[1280] >= 2 and rows[320] > rows[1280]     # legend + the run, more lines on 320 px
    # every frame of a video has one size, whatever its caption says
    n = 1000
    track = RunTrack("r", np.full((n, 4), 10.0), np.arange(n), tuple(frozenset() for _ in range(n)), None, None, False)
    gt = np.full((n, 4), 20.0)
    gt[0] = np.nan
    sizes = {draw_frame(np.zeros((240, 320, 3), np.uint8), k, gt, [track], run_colours(1)).shape for k in (0, 5, n - 1)}
    assert len(sizes) == 1


def test_contact_sheet_and_one_line_errors(runs, capsys):
    tmp, dirs = runs
    sheet = tmp / "sheet.png"
    assert main(["play", str(dirs[1]), "--sequence", SEQ, "--out", str(sheet), "--sheet", "4"]) == 0
    img = cv2.imread(str(sheet))
    assert img is not None and img.shape[1] == 1800
    assert main(["play", str(dirs[1]), "--sequence", "nope", "--out", str(tmp / "x.mp4")]) == 2
    assert main(["play", str(dirs[1]), "--sequence", SEQ, "--out", str(tmp / "x.mp4"), "--frames", "0:500"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("mata-eval play: ") for line in err)
    # a sheet into a video name, a video into an image name, a negative sheet: one line each, before
    # any frame is drawn (QA pass: an OpenCV traceback, or the video's message for a sheet)
    for args, words in ((["--sheet", "4", "--out", str(tmp / "s.mp4")], "a contact sheet is an image"),
                        (["--out", str(tmp / "v.png")], "expected a .mp4 or .avi file name"),
                        (["--sheet", "-3", "--out", str(tmp / "s.png")], "--sheet -3: expected a number of frames"),
                        (["--sheet", "0", "--out", str(tmp / "s.png")], "--sheet 0: expected a number of frames")):
        assert main(["play", str(dirs[1]), "--sequence", SEQ] + args) == 2
        assert words in capsys.readouterr().err


def test_mata_run_records_the_trackers_box_and_search_region(runs):
    _, dirs = runs
    with open(dirs[1] / f"{SEQ}.frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    called = [r for r in rows if r["tracker_x"] != "nan"]
    assert len(called) == len(rows) - 1  # LTP: every frame but the initialisation
    for r in called:
        cx = float(r["tracker_x"]) + float(r["tracker_w"]) / 2
        sx, sw = float(r["search_x"]), float(r["search_w"])
        assert sw > float(r["tracker_w"]) and sx <= cx <= sx + sw  # the box found lies in the window searched
    track = read_run_track(dirs[1], SEQ, len(rows))
    assert track.mata and track.search is not None and track.tracker_box is not None

