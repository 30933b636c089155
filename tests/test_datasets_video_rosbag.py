"""Flight inputs: a video file and ROS 1 / ROS 2 / MCAP bags (written here with OpenCV and the
rosbags library) read back frame for frame, ground truth matched by stamp, and a live run on a
video without ground truth giving outputs and timings but no score."""

from __future__ import annotations

import importlib.util
import textwrap
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from mata_eval.core.types import Box
from mata_eval.data.datasets.annotations import DatasetError
from mata_eval.data.datasets.rosbag import RosbagDataset, box_of
from mata_eval.data.datasets.video import VideoDataset
from mata_eval.run.config import load_experiment
from mata_eval.run.runner import run_experiment
from mata_eval.score.evaluate import evaluate_experiment

W, H, N = 96, 64, 12


def frame(k: int) -> np.ndarray:
    """Frame k: grey level 10 + 20 k, a 16x16 white square at x = 8 + 4 k."""
    img = np.full((H, W, 3), 10 + 20 * k, np.uint8)
    img[20:36, 8 + 4 * k: 24 + 4 * k] = 255
    return img


# --- video -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def video(tmp_path_factory):
    path = tmp_path_factory.mktemp("video") / "flight.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (W, H))
    assert writer.isOpened(), "OpenCV cannot write MJPG/AVI here"
    for k in range(N):
        writer.write(frame(k))
    writer.release()
    return path


def test_video_frames_in_order_and_by_seeking(video):
    (seq,) = VideoDataset(VideoDataset.Params(path=str(video), init_box=[8, 20, 16, 16])).sequences()
    assert (seq.name, len(seq), seq.fps) == ("flight", N, 25.0)
    assert seq.init_box == Box(8, 20, 16, 16) and np.isnan(seq.groundtruth).all()
    for k in [0, 1, 2, 7, 3, 11]:  # sequential, then seeks forward and back
        assert abs(float(seq.image(k)[50:, :, 1].mean()) - (10 + 20 * k)) < 4, k  # JPEG-compressed


def test_video_with_ground_truth_and_errors(video, tmp_path):
    gt = tmp_path / "gt.txt"
    gt.write_text("".join(f"{8 + 4 * k},20,16,16\n" for k in range(N)))
    (seq,) = VideoDataset(VideoDataset.Params(path=str(video), groundtruth=str(gt))).sequences()
    assert seq.init_box == Box(8, 20, 16, 16) and seq.groundtruth[5].tolist() == [28, 20, 16, 16]
    gt.write_text("8,20,16,16\n")
    with pytest.raises(DatasetError, match=r"gt.txt: 1 ground-truth lines but 12 frames"):
        VideoDataset(VideoDataset.Params(path=str(video), groundtruth=str(gt))).sequences()
    gt.write_text("8,20,16,16\n" * (N + 5))           # another sequence's file: refused, not cut
    with pytest.raises(DatasetError, match=r"gt.txt: 17 ground-truth lines but 12 frames"):
        VideoDataset(VideoDataset.Params(path=str(video), groundtruth=str(gt))).sequences()
    (seq,) = VideoDataset(VideoDataset.Params(path=str(video), groundtruth=str(gt), frames=10)).sequences()
    assert len(seq) == 10 and len(seq.groundtruth) == 10   # the first 10 of both, as asked
    with pytest.raises(ValueError, match=r"video: give init_box"):
        VideoDataset.Params(path=str(video))
    with pytest.raises(DatasetError, match=r"video: file not found: .*nope.mp4"):
        VideoDataset(VideoDataset.Params(path=str(tmp_path / "nope.mp4"), init_box=[1, 1, 2, 2])).sequences()


def test_live_run_on_a_video_without_ground_truth_gives_outputs_and_timings_only(video, tmp_path):
    exp_file = tmp_path / "flight.yaml"
    exp_file.write_text(textwrap.dedent(f"""
        output: {tmp_path / 'out'}
        dataset: {{name: video, path: {video}, init_box: [8, 20, 16, 16]}}
        tracker: {{name: kcf}}
        egomotion: {{name: grid_lk}}
        estimator: {{name: homography_ekf}}
        protocol: {{name: live}}
    """))
    exp = load_experiment(exp_file)
    assert [o.status for o in run_experiment(exp, jobs=1, progress=False, log=lambda s: None)] == ["done"]
    run = exp.output / exp.runs[0].name
    boxes = np.loadtxt(run / "flight.txt", delimiter=",")
    assert boxes.shape == (N, 4) and np.isfinite(boxes).all()
    (scores,) = evaluate_experiment(exp)
    assert scores.summary.overall.n_sequences == 0 and np.isnan(scores.summary.overall.sr)
    assert scores.frequencies["tracker"].starts > 1
    # played back on its frames (QA pass: `play` asked the video plugin for `sequences`)
    from mata_eval.report.playback import play

    out, n = play([run], "flight", tmp_path / "flight.png", sheet=4)
    assert n == 4 and cv2.imread(str(out)).shape[1] == 1800


# --- ROS bags ------------------------------------------------------------------------------------

requires_rosbags = pytest.mark.skipif(importlib.util.find_spec("rosbags") is None,
                                      reason="the rosbags library (extra `rosbag`) is not installed")


def write_bag(path, kind: str, image_type: str, gt_type: str, skip_gt=()):
    """A bag of N images (header stamps 1 s + k / 20 s, received 5 ms later) and their boxes."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer
        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    with writer:
        cam = writer.add_connection("/cam", image_type, typestore=ts)
        box = writer.add_connection("/target", gt_type, typestore=ts)
        for k in range(N):
            ns = 1_000_000_000 + k * 50_000_000
            stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            header = T["std_msgs/msg/Header"](**({"seq": k} if ros1 else {}), stamp=stamp, frame_id="cam")
            img = frame(k)
            if image_type.endswith("CompressedImage"):
                msg = T[image_type](header=header, format="png", data=cv2.imencode(".png", img)[1].reshape(-1))
            else:  # rgb8, the usual camera-driver encoding
                msg = T[image_type](header=header, height=H, width=W, encoding="rgb8", is_bigendian=0, step=3 * W,
                                    data=img[:, :, ::-1].reshape(-1).copy())
            writer.write(cam, ns + 5_000_000, serialize(msg, image_type))
            if k in skip_gt:
                continue
            x = 8 + 4 * k
            if gt_type.endswith("RegionOfInterest"):  # no header: matched by receive time
                gt = T[gt_type](x_offset=x, y_offset=20, height=16, width=16, do_rectify=False)
            else:
                P = T["geometry_msgs/msg/Point32"]
                pts = [P(x=float(x), y=20.0, z=0.0), P(x=x + 16.0, y=20.0, z=0.0), P(x=x + 16.0, y=36.0, z=0.0)]
                gt = T[gt_type](header=header, polygon=T["geometry_msgs/msg/Polygon"](points=pts))
            writer.write(box, ns + 7_000_000, serialize(gt, gt_type))


@requires_rosbags
@pytest.mark.parametrize("kind,image_type,gt_type", [
    ("ros1", "sensor_msgs/msg/Image", "sensor_msgs/msg/RegionOfInterest"),
    ("sqlite3", "sensor_msgs/msg/CompressedImage", "geometry_msgs/msg/PolygonStamped"),
    ("mcap", "sensor_msgs/msg/Image", "geometry_msgs/msg/PolygonStamped"),
])
def test_bag_frames_and_ground_truth(tmp_path, kind, image_type, gt_type):
    path = tmp_path / ("flight.bag" if kind == "ros1" else "flight")
    write_bag(path, kind, image_type, gt_type, skip_gt=(4,))
    (seq,) = RosbagDataset(RosbagDataset.Params(path=str(path), image_topic="/cam", gt_topic="/target")).sequences()
    assert seq.name == "flight" and len(seq) == N and seq.fps == pytest.approx(20.0)
    for k in [0, 5, 11, 3]:  # lossless encodings: the exact pixels, in any order
        np.testing.assert_array_equal(seq.image(k), frame(k))
    expected = np.array([[8 + 4 * k, 20, 16, 16] for k in range(N)], float)
    expected[4] = np.nan  # no message for frame 4: not scored
    np.testing.assert_array_equal(seq.groundtruth, expected)
    assert seq.init_box == Box(8, 20, 16, 16)


@requires_rosbags
def test_bare_mcap_file_and_errors(tmp_path):
    write_bag(tmp_path / "b", "mcap", "sensor_msgs/msg/Image", "sensor_msgs/msg/RegionOfInterest")
    (mcap,) = (tmp_path / "b").glob("*.mcap")
    (seq,) = RosbagDataset(RosbagDataset.Params(path=str(mcap), image_topic="/cam", init_box=[1, 2, 3, 4])).sequences()
    assert len(seq) == N and seq.init_box == Box(1, 2, 3, 4) and np.isnan(seq.groundtruth).all()
    np.testing.assert_array_equal(seq.image(7), frame(7))
    with pytest.raises(DatasetError, match=r"image_topic: no topic '/camera' in .*; its topics: /cam "):
        RosbagDataset(RosbagDataset.Params(path=str(mcap), image_topic="/camera", init_box=[1, 2, 3, 4])).sequences()
    with pytest.raises(DatasetError, match=r"image_topic '/target' carries sensor_msgs/msg/RegionOfInterest"):
        RosbagDataset(RosbagDataset.Params(path=str(mcap), image_topic="/target", init_box=[1, 2, 3, 4])).sequences()
    with pytest.raises(ValueError, match=r"rosbag: give init_box"):
        RosbagDataset.Params(path=str(mcap), image_topic="/cam")


def test_vision_msgs_boxes_are_centre_and_size():
    centre = SimpleNamespace(x=50.0, y=40.0, theta=0.0)
    bbox = SimpleNamespace(center=centre, size_x=20.0, size_y=10.0)
    assert box_of(bbox).tolist() == [40.0, 35.0, 20.0, 10.0]
    # vision_msgs 4 (ROS 2 Humble): the centre is a Pose2D with a position
    bbox4 = SimpleNamespace(center=SimpleNamespace(position=SimpleNamespace(x=50.0, y=40.0)), size_x=20.0, size_y=10.0)
    assert box_of(SimpleNamespace(header=None, bbox=bbox4)).tolist() == [40.0, 35.0, 20.0, 10.0]
    assert np.isnan(box_of(SimpleNamespace(header=None, detections=[]))).all()
