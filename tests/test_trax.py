"""Trackers out of process over TraX (plugins/trackers/trax.py): what crosses the protocol (frames
byte for byte, the MATA prior, the confidence and its fallback), misbehaving trackers (crash,
hang, no TraX at all) failing their sequence with the reason and always reaped, and a real
tracker (NanoTrack, VitTrack) served from another process giving the in-process plugin's boxes."""

from __future__ import annotations

import sys
import time
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from mata_eval.core.errors import ConfigError
from mata_eval.core.registry import load_registry
from mata_eval.core.sequence import Sequence
from mata_eval.data.datasets.annotations import read_boxes
from mata_eval.run.scheduler import run_sequence
from mata_eval.types import Box

pytest.importorskip("trax", reason="the vot-trax package (extra `trax`) is not installed")

from mata_eval_plugins.trackers.trax import TrackerProcessError, TraxTracker  # noqa: E402

SERVERS = Path(__file__).parent / "trax_servers"


def scripted(*args: str, **params) -> TraxTracker:
    command = [sys.executable, str(SERVERS / "scripted_server.py"), *args]
    return TraxTracker(TraxTracker.Params(command=command, **params))


def frame(seed: int, h: int = 48, w: int = 64) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def gone(pid: int, within_s: float = 5.0) -> bool:
    """The process no longer runs (absent, or a zombie its new parent has not collected yet)."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError):
            return True
        if state == "Z":
            return True
        time.sleep(0.05)
    return False


# --- what crosses the protocol -------------------------------------------------------------------

@pytest.mark.parametrize("images", ["path", "memory"])
def test_frames_arrive_byte_for_byte_and_the_prior_moves_the_box(images):
    tracker = scripted("--images", images)
    try:
        img0 = frame(0)
        tracker.initialize(img0, Box(10.0, 12.0, 8.0, 6.0))
        img1 = frame(1)
        out = tracker.track(img1, prior=(30.123456789, 20.5))
        assert out.extra["crc"] == zlib.crc32(img1.tobytes())  # BGR, unchanged, through either format
        # libtrax writes regions with 4 decimals: the prior comes back within 1e-4 px
        assert out.box.center == pytest.approx((30.123456789, 20.5), abs=1e-4)
        assert (out.box.w, out.box.h) == (8.0, 6.0)
        # no prior: the tracker keeps its own box
        out = tracker.track(frame(2))
        assert out.box.as_array() == pytest.approx([10.0, 12.0, 8.0, 6.0])
    finally:
        tracker.close()


@pytest.mark.parametrize("reported, default, expected", [
    (None, 1.0, 1.0),      # no `confidence` property: the documented fallback
    (None, 0.3, 0.3),
    ("0.625", 1.0, 0.625),
    ("1.7", 1.0, 1.0),     # clipped to [0, 1]
])
def test_confidence_property_and_its_fallback(reported, default, expected):
    args = () if reported is None else ("--confidence", reported)
    tracker = scripted(*args, default_confidence=default)
    try:
        tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
        assert tracker.track(frame(1)).confidence == expected
    finally:
        tracker.close()


def test_a_confidence_that_is_not_a_number_fails_with_its_value():
    tracker = scripted("--confidence", "high")
    tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
    pid = tracker.pid
    with pytest.raises(TrackerProcessError, match=r"`confidence` property of frame 1 is not a number: 'high'"):
        tracker.track(frame(1))
    assert gone(pid)


def test_special_region_is_no_target():
    tracker = scripted("--special-at", "1", "--confidence", "0.9")
    try:
        tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
        out = tracker.track(frame(1))
        assert (out.box.as_array() == 0).all() and out.confidence == 0.0
    finally:
        tracker.close()


@pytest.fixture(scope="module")
def c_tracker(tmp_path_factory) -> Path:
    """tests/trax_servers/prior_tracker.c built against the libtrax.so inside the vot-trax wheel."""
    import shutil
    import subprocess

    import trax

    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler (cc) to build the C TraX tracker")
    lib = Path(trax.__file__).parent
    if not (lib / "libtrax.so").is_file():
        pytest.skip(f"vot-trax has no libtrax.so in {lib}")
    exe = tmp_path_factory.mktemp("c_tracker") / "prior_tracker"
    subprocess.run([compiler, "-O2", str(SERVERS / "prior_tracker.c"), "-o", str(exe), f"-L{lib}", "-l:libtrax.so",
                    f"-Wl,-rpath,{lib}"], check=True, capture_output=True)
    return exe


def test_a_tracker_written_in_c_reads_the_frame_and_the_prior(c_tracker):
    """The C tracker declares only `path` images: it reads the BMP itself and reports the mean
    byte / 255 as its confidence, and centres its box on the prior it received."""
    tracker = TraxTracker(TraxTracker.Params(command=[str(c_tracker)]))
    try:
        tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
        img = frame(1, h=37, w=53)  # odd width: BMP rows are padded
        out = tracker.track(img, prior=(30.25, 20.5))
        assert out.confidence == pytest.approx(img.mean() / 255.0, rel=1e-6)
        assert out.box.as_array() == pytest.approx([26.25, 17.5, 8.0, 6.0], abs=1e-4)
        assert tracker.track(frame(2)).box.as_array() == pytest.approx([26.25, 17.5, 8.0, 6.0], abs=1e-4)
    finally:
        tracker.close()


# --- misbehaving trackers -------------------------------------------------------------------------

def test_a_crash_fails_with_exit_code_and_stderr_and_is_reaped():
    tracker = scripted("--crash-at", "2")
    tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
    pid = tracker.pid
    tracker.track(frame(1))
    with pytest.raises(TrackerProcessError) as err:
        tracker.track(frame(2))
    msg = str(err.value)
    assert "exited with code 3 during frame 2" in msg
    assert "scripted tracker: crashing at frame 2" in msg  # the tracker's stderr, quoted
    assert tracker.pid is None and gone(pid)


def test_a_clean_exit_at_initialize_points_at_the_single_object_calls():
    """QA pass 15b: a C tracker on libtrax's single-object calls ends the session at initialize
    with exit code 0, and the error did not say why."""
    with pytest.raises(TrackerProcessError, match="exited with code 0 during initialize .*trax_server_wait_mot"):
        scripted("--exit-at-init").initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
    tracker = scripted("--crash-at", "1")
    tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
    with pytest.raises(TrackerProcessError) as err:   # a failure elsewhere is not given the hint
        tracker.track(frame(1))
    assert "trax_server_wait_mot" not in str(err.value)


def test_a_hang_times_out_and_the_whole_process_group_is_killed():
    tracker = scripted("--hang-at", "1", timeout_s=1.0)
    tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
    pid = tracker.pid
    t0 = time.monotonic()
    with pytest.raises(TrackerProcessError, match=r"no answer to frame 1 within 1 s \(killed\)") as err:
        tracker.track(frame(1))
    assert time.monotonic() - t0 < 5.0
    child = int(str(err.value).rsplit("child ", 1)[1].split()[0])  # the `sleep` it started
    assert gone(pid) and gone(child)


def test_a_program_that_does_not_speak_trax_times_out_at_the_handshake():
    tracker = TraxTracker(TraxTracker.Params(command=["sleep", "30"], timeout_s=0.5))
    with pytest.raises(TrackerProcessError, match="no answer to the handshake within 0.5 s"):
        tracker.initialize(frame(0), Box(1.0, 1.0, 4.0, 4.0))


def test_a_missing_program_says_it_cannot_start():
    tracker = TraxTracker(TraxTracker.Params(command=["/nonexistent/tracker"]))
    with pytest.raises(TrackerProcessError, match=r"cannot start \['/nonexistent/tracker'\]"):
        tracker.initialize(frame(0), Box(1.0, 1.0, 4.0, 4.0))


def test_close_ends_the_process_and_a_new_initialise_starts_a_fresh_one():
    tracker = scripted()
    tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
    first = tracker.pid
    tracker.initialize(frame(0), Box(10.0, 12.0, 8.0, 6.0))
    assert tracker.pid != first and gone(first)
    second = tracker.pid
    tracker.close()
    tracker.close()  # idempotent
    assert gone(second)


# --- through an experiment file and the runner ----------------------------------------------------

def _experiment(tmp_path: Path, tracker_yaml: str) -> Path:
    seq = tmp_path / "data" / "toy"
    (seq / "img").mkdir(parents=True, exist_ok=True)
    for k in range(4):
        cv2.imwrite(str(seq / "img" / f"{k:04d}.png"), frame(k))
    (seq / "groundtruth_rect.txt").write_text("10,12,8,6\n" * 4)
    exp = tmp_path / "exp.yaml"
    exp.write_text(f"output: {tmp_path / 'out'}\n"
                   f"dataset: {{name: folder, root: {tmp_path / 'data'}}}\n"
                   f"tracker: {tracker_yaml}\n")
    return exp


def test_runner_records_the_crash_as_a_failed_sequence_and_reaps_every_process(tmp_path):
    from mata_eval.run.config import load_experiment
    from mata_eval.run.runner import run_experiment

    script = SERVERS / "scripted_server.py"
    pid_file = tmp_path / "pid"
    exp = _experiment(tmp_path, f"{{name: trax, command: [{sys.executable}, {script}, --crash-at, '2', "
                                f"--pid-file, {pid_file}], env: {{OMP_NUM_THREADS: 1}}, timeout_s: 10}}")
    run_experiment(load_experiment(exp), progress=False, log=lambda line: None)
    failed = (tmp_path / "out" / "exp" / "toy.failed.json").read_text()
    assert "exited with code 3 during frame 2" in failed
    assert gone(int(pid_file.read_text()))

    exp = _experiment(tmp_path, f"{{name: trax, command: [{sys.executable}, {script}, --pid-file, {pid_file}]}}")
    run_experiment(load_experiment(exp), force=True, progress=False, log=lambda line: None)
    assert read_boxes(tmp_path / "out" / "exp" / "toy.txt").shape == (4, 4)
    assert gone(int(pid_file.read_text()))  # a finished sequence closes its tracker too


@pytest.mark.parametrize("block, message", [
    ("{name: trax}", "missing required parameter(s): command"),
    ("{name: trax, command: []}", "`command` must be the tracker's command line"),
    ("{name: trax, command: [x], timeout_s: 0}", "`timeout_s` must be a positive number"),
    ("{name: trax, command: [x], env: {A: [1]}}", "`env.A` must be a string"),
])
def test_bad_blocks_name_the_line_and_the_key(tmp_path, block, message):
    from mata_eval.run.config import load_experiment

    exp = _experiment(tmp_path, block)
    with pytest.raises(ConfigError) as err:
        load_experiment(exp, load_registry())
    assert f"{exp}:3: tracker" in str(err.value) and message in str(err.value)


# --- real trackers in another process -------------------------------------------------------------

FRAMES = 40


@pytest.fixture(scope="module")
def mountainbike(shared_data) -> Sequence:
    folder = shared_data / "sequences" / "aerial30" / "MountainBike6"
    gt = read_boxes(folder / "groundtruth_rect.txt")[:FRAMES]
    paths = tuple(str(p) for p in sorted((folder / "img").glob("*.jpg"))[:FRAMES])
    return Sequence("MountainBike6", gt, 30.0, frame_paths=paths)


def _models(shared: Path) -> dict[str, list[str]]:
    m = shared / "models"
    return {"nanotrack": [f"backbone={m / 'nanotrack/v2/nanotrack_backbone_sim.onnx'}",
                          f"head={m / 'nanotrack/v2/nanotrack_head_sim.onnx'}"],
            "vittrack": [f"model={m / 'vittrack/object_tracking_vittrack_2023sep.onnx'}"]}


@pytest.mark.parametrize("plugin", ["nanotrack", "vittrack"])
def test_real_tracker_over_trax_gives_the_in_process_boxes(plugin, mountainbike, shared_data):
    """The shipped plugin in a separate Python process behind TraX, in the MATA loop (EKF with
    feedback, so every frame sends a prior): the same boxes and confidences as in process."""
    pytest.importorskip("onnxruntime")
    reg = load_registry()
    args = _models(shared_data)[plugin]
    entry = reg.get("tracker", plugin)
    in_process = entry.cls(entry.cls.Params(**dict(a.split("=", 1) for a in args)))
    remote = TraxTracker(TraxTracker.Params(command=[sys.executable, str(SERVERS / "plugin_server.py"), plugin, *args],
                                            env={"OMP_NUM_THREADS": "1"}))

    def run(tracker):
        ekf = reg.get("estimator", "homography_ekf").cls()
        return run_sequence(mountainbike, tracker, None, ekf, reg.get("protocol", "ltp").cls(),
                            np.random.default_rng(0), feedback=True)

    a = run(in_process)
    try:
        b = run(remote)
    finally:
        remote.close()
    # both plugins report OpenCV-style integer boxes: exact through libtrax's 4 decimals
    np.testing.assert_array_equal(a.boxes, b.boxes)
    np.testing.assert_array_equal(a.confidence, b.confidence)  # sent as repr(): exact
    centres = a.boxes[:, :2] + a.boxes[:, 2:] / 2
    assert np.ptp(centres, axis=0).max() > 20, "the boxes should move: otherwise the comparison says little"


def test_the_preflight_names_a_missing_command_and_a_missing_client(monkeypatch, tmp_path):
    """QA pass: a command that does not exist, or vot-trax not installed, passed `validate` and
    failed every sequence (the latter with a bare ImportError)."""
    from mata_eval_plugins.trackers.backends import BackendUnavailable

    scripted().check()                                          # python + a script: fine
    TraxTracker(TraxTracker.Params(command=["scripted_server.py"], cwd=str(SERVERS))).check()  # relative to cwd
    with pytest.raises(BackendUnavailable, match=r"trax: command not found: '/nonexistent/tracker'"):
        TraxTracker(TraxTracker.Params(command=["/nonexistent/tracker"])).check()
    monkeypatch.setitem(sys.modules, "trax", None)              # import trax now fails
    with pytest.raises(BackendUnavailable, match=r"needs the TraX client \(vot-trax\): pip install 'mata-eval\[trax\]'"):
        scripted().check()
