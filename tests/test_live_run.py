"""A live run from an experiment file through the runner, with the real blocks (kcf, grid_lk,
homography_ekf) on a small rendered folder dataset; then every command that reads run folders
(eval, report, timeline, profile) works on it unchanged."""

from __future__ import annotations

import csv
import json
import textwrap

import cv2
import numpy as np
import pytest

from mata_eval.cli import main
from mata_eval.run.config import load_experiment
from mata_eval.run.runner import run_experiment
from mata_eval.run.scheduler import read_trace_csv

N, FPS = 24, 30.0


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """One 24-frame sequence: a textured ground sliding 2 px a frame, a bright square on it."""
    root = tmp_path_factory.mktemp("live_data")
    seq = root / "glide"
    (seq / "img").mkdir(parents=True)
    rng = np.random.default_rng(0)
    ground = cv2.GaussianBlur(rng.integers(0, 255, (300, 400), np.uint8), (0, 0), 2.0)
    rows = []
    for k in range(N):
        img = cv2.cvtColor(ground[20:260, 2 * k: 2 * k + 320], cv2.COLOR_GRAY2BGR)
        x, y = 100 + 3 * k, 90 + k
        img[y: y + 30, x: x + 30] = (40, 220, 250)
        cv2.imwrite(str(seq / "img" / f"{k + 1:04d}.jpg"), img)
        rows.append(f"{x},{y},30,30")
    (seq / "groundtruth_rect.txt").write_text("\n".join(rows) + "\n")
    return root


@pytest.fixture(scope="module")
def live_run(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("live_out")
    exp_file = out / "live.yaml"
    exp_file.write_text(textwrap.dedent(f"""
        name: live-test
        output: {out / 'results'}
        dataset: {{name: folder, root: {dataset}, fps: {FPS}}}
        tracker: {{name: kcf}}
        egomotion: {{name: grid_lk}}
        estimator: {{name: homography_ekf}}
        protocol: {{name: live, time_scale: {{tracker: 3}}}}
    """))
    exp = load_experiment(exp_file)
    outcomes = run_experiment(exp, jobs=1, progress=False, log=lambda s: None)
    assert [o.status for o in outcomes] == ["done"], outcomes
    return exp_file, exp.output / exp.runs[0].name


def test_live_run_folder_has_the_usual_files_with_real_times(live_run):
    _, run = live_run
    boxes = np.loadtxt(run / "glide.txt", delimiter=",")
    assert boxes.shape == (N, 4)
    with open(run / "glide.frames.csv") as f:
        frames = list(csv.DictReader(f))
    assert len(frames) == N and {"tracker_ms", "egomotion_ms", "estimator_ms", "source_frame"} <= set(frames[0])
    trace = read_trace_csv((run / "glide.trace.csv").read_text())
    cam = [e.t for e in trace if e.block == "camera" and e.event == "publish"]
    assert len(cam) == N
    # real times: the camera publishes frame k at k / FPS, never before; lateness does not add up
    # from frame to frame (a camera sleeping 1 / FPS after each publish, or waiting for the
    # blocks, falls further behind each frame). Measured with the real blocks on the 2 shared
    # cores at load 10-20 plus two busy loops: median lateness <= 10 ms, single frames up to
    # 110 ms (the camera thread not scheduled; frame 0 waits for the block threads to start).
    lateness = np.array(cam) - np.arange(N) / FPS
    assert lateness.min() > -1e-3
    assert np.median(lateness) < 0.5 / FPS and lateness.max() < 5 / FPS, np.round(1e3 * lateness, 1)
    # the scored box of each frame is the output of a frame already captured
    src = np.array([int(r["source_frame"]) for r in frames])
    assert (src <= np.arange(N)).all() and (src[1:] >= src[:-1]).all()
    # each tracker call's box and search region, as EOP's runs have them for `play` (QA pass:
    # missing, so a live run was played without the tracker's box it names in the legend)
    called = [r for r in frames[1:] if r["tracker_ms"] != "nan"]        # frame 0: the initialisation
    assert called and all(np.isfinite([float(r[c]) for c in ("tracker_x", "tracker_w", "search_x", "search_w")]).all()
                          for r in called)
    assert all(r["tracker_x"] == "nan" for r in frames if r["tracker_ms"] == "nan")
    # the prior each call was handed, and block B's record of each of its calls, as EOP's runs have
    assert any(r["prior_x"] != "nan" for r in called)
    moved = [r for r in frames[1:] if r["egomotion_ms"] != "nan"]
    assert moved and all(r["motion_valid"] in ("0", "1") and float(r["motion_inliers"]) >= 0 for r in moved)
    manifest = json.loads((run / "manifest.json").read_text())
    assert manifest["config"]["protocol"]["name"] == "live"


def test_eval_report_timeline_and_profile_work_on_a_live_run(live_run, dataset, tmp_path, capsys):
    exp_file, run = live_run
    assert main(["eval", str(run), "--dataset", "folder", "--root", str(dataset), "--set", f"fps={FPS}"]) == 0
    scores = json.loads((run / "scores.json").read_text())
    assert 0.0 <= scores["summary"]["overall"]["sr"] <= 1.0
    assert scores["frequencies"]["estimator"]["starts"] > N / 2  # ticks on most frames
    assert main(["report", str(run)]) == 0
    assert main(["timeline", str(run), "glide", "--out", str(tmp_path / "t.png")]) == 0
    assert (tmp_path / "t.png").stat().st_size > 0
    capsys.readouterr()
    assert main(["timeline", str(run), "glide", "--frames", "1000:1100", "--out", str(tmp_path / "e.png")]) == 2
    assert "starts after the trace of glide" in capsys.readouterr().err and not (tmp_path / "e.png").exists()
    assert main(["timeline", str(run), "glide", "--frames", f"1:{N + 100}", "--out", str(tmp_path / "e.png")]) == 0
    assert f"frames 1:{N}: the trace of glide ends at frame {N - 1}" in capsys.readouterr().out   # (QA pass 14)
    assert main(["profile", str(exp_file), "--frames", "5", "--warmup", "1",
                 "--out", str(tmp_path / "p.json")]) == 0
    assert set(json.loads((tmp_path / "p.json").read_text())["blocks"]) == {"tracker", "egomotion", "estimator"}


def test_ctrl_c_stops_mata_eval_run_cleanly(dataset, tmp_path):
    """SIGINT to `mata-eval run` in the middle of a live sequence (a 5 fps camera: 4.8 s): the
    process ends within a second or two, and the interrupted sequence is not marked finished."""
    import signal
    import subprocess
    import sys
    import time

    exp_file = tmp_path / "slow.yaml"
    exp_file.write_text(textwrap.dedent(f"""
        output: {tmp_path / 'results'}
        dataset: {{name: folder, root: {dataset}, fps: 5}}
        tracker: {{name: kcf}}
        egomotion: {{name: grid_lk}}
        estimator: {{name: homography_ekf}}
        protocol: {{name: live, time_scale: {{tracker: 20}}}}
    """))
    proc = subprocess.Popen([sys.executable, "-m", "mata_eval", "run", str(exp_file), "-j", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    run = tmp_path / "results" / "slow"
    deadline = time.monotonic() + 60
    while not (run / "manifest.json").is_file() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.5)  # the camera is running
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=20)
    assert time.monotonic() - t0 < 3.0
    assert proc.returncode != 0
    assert not (run / "glide.txt").exists() and not (run / "glide.trace.csv").exists()
