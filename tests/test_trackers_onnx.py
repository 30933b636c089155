"""VitTrack and NanoTrack through ONNX Runtime: model-file errors, the ONNX shape relaxation,
parity with cv2.TrackerVit / cv2.TrackerNano on real frames, confidence range, and the MATA
prior moving the search region (real data: skipped without ../shared/data)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from mata_eval.types import Box
from mata_eval_plugins.trackers import nanotrack as nano_mod
from mata_eval_plugins.trackers.model_files import ModelFileNotFound, resolve_model
from mata_eval_plugins.trackers.nanotrack import NanoTrack, relax_spatial_dims
from mata_eval_plugins.trackers.vittrack import VitTrack, blob_scale, installed_opencv_port

pytest.importorskip("onnxruntime")


# --- helpers --------------------------------------------------------------------------------

def load_sequence(folder: Path, limit: int):
    """First ``limit`` BGR frames and x, y, w, h ground truth (VOT polygons -> min/max box)."""
    name = "groundtruth_rect.txt" if (folder / "groundtruth_rect.txt").is_file() else "groundtruth.txt"
    rows = [[float(v) for v in line.replace("\t", ",").split(",") if v]
            for line in (folder / name).read_text().splitlines() if line.strip()]
    gt = np.array(rows[:limit])
    if gt.shape[1] == 8:
        xs, ys = gt[:, 0::2], gt[:, 1::2]
        gt = np.stack([xs.min(1), ys.min(1), xs.max(1) - xs.min(1), ys.max(1) - ys.min(1)], axis=1)
    img_dir = next(d for d in (folder / "img", folder / "imgs") if d.is_dir())
    frames = [cv2.imread(str(p)) for p in sorted(img_dir.glob("*.jpg"))[:limit]]
    return frames, gt


def iou_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    x1, y1 = np.maximum(a[:, 0], b[:, 0]), np.maximum(a[:, 1], b[:, 1])
    x2 = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2])
    y2 = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    return inter / (a[:, 2] * a[:, 3] + b[:, 2] * b[:, 3] - inter)


def run_pair(ours, ref, frames, init):
    ours.initialize(frames[0], Box.from_array(init))
    ref.init(frames[0], tuple(int(v) for v in init))
    a, b, last, outs = [], [], np.asarray(init, float), []
    for f in frames[1:]:
        out = ours.track(f)
        ok, box = ref.update(f)
        last = np.asarray(box, float) if ok else last
        a.append(out.box.as_array())
        b.append(last)
        outs.append(out)
    return np.array(a), np.array(b), outs


def cv2_vit(shared):
    params = cv2.TrackerVit_Params()
    params.net = str(shared / "models/vittrack/object_tracking_vittrack_2023sep.onnx")
    return cv2.TrackerVit_create(params)


def cv2_nano(shared):
    params = cv2.TrackerNano_Params()
    params.backbone = str(shared / "models/nanotrack/v2/nanotrack_backbone_sim.onnx")
    params.neckhead = str(shared / "models/nanotrack/v2/nanotrack_head_sim.onnx")
    return cv2.TrackerNano_create(params)


@pytest.fixture()
def models(shared_data, monkeypatch):
    monkeypatch.setenv("MATA_VITTRACK_ONNX", str(shared_data / "models/vittrack/object_tracking_vittrack_2023sep.onnx"))
    monkeypatch.setenv("MATA_NANOTRACK_BACKBONE", str(shared_data / "models/nanotrack/v2/nanotrack_backbone_sim.onnx"))
    monkeypatch.setenv("MATA_NANOTRACK_HEAD", str(shared_data / "models/nanotrack/v2/nanotrack_head_sim.onnx"))
    return shared_data


# --- without real data ----------------------------------------------------------------------

def test_missing_model_names_file_and_source(tmp_path, monkeypatch):
    with pytest.raises(ModelFileNotFound, match=r"object_tracking_vittrack_2023sep\.onnx.*opencv_zoo"):
        VitTrack(VitTrack.Params(model=str(tmp_path / "nope.onnx")))
    monkeypatch.setenv("MATA_NANOTRACK_BACKBONE", str(tmp_path / "missing_dir"))
    with pytest.raises(ModelFileNotFound, match=r"nanotrack_backbone_sim\.onnx.*MATA_NANOTRACK_BACKBONE.*SiamTrackers"):
        NanoTrack()
    monkeypatch.delenv("MATA_NANOTRACK_BACKBONE")
    monkeypatch.setenv("MATA_SHARED_DATA", str(tmp_path))          # nothing there either
    with pytest.raises(ModelFileNotFound, match=r"nanotrack_backbone_sim\.onnx.*'backbone'"):
        resolve_model("nanotrack_backbone", None)


def test_opencv_blob_scale_is_the_quaternion_inverse_up_to_5_0():
    # cv::Scalar's `double / Scalar` is conj(s) / |s|^2: for s = (a, b, c, 0) that is
    # (a, -b, -c) / (a^2 + b^2 + c^2). Computed by hand for the ImageNet std:
    mean, scale, swap = blob_scale("opencv")
    n = 0.229 ** 2 + 0.224 ** 2 + 0.225 ** 2
    assert scale == pytest.approx(np.array([0.229, -0.224, -0.225]) / n / 255.0, rel=1e-6)
    assert mean == pytest.approx([123.675, 116.28, 103.53], rel=1e-6) and not swap
    _, scale, swap = blob_scale("opencv", "5.1")                   # 5.1: element-wise 1 / (255 std)
    assert scale == pytest.approx(1.0 / (255.0 * np.array([0.229, 0.224, 0.225])), rel=1e-6) and not swap
    _, scale, swap = blob_scale("imagenet")
    assert swap and scale == pytest.approx(1.0 / (255.0 * np.array([0.229, 0.224, 0.225])), rel=1e-6)


def test_protobuf_relaxation_round_trip():
    # Hand-built ModelProto: graph { input { name "input" type { tensor_type { elem_type 1
    # shape { dim {dim_value 1} dim {dim_value 3} dim {dim_value 255} dim {dim_value 255} } } } } }
    def ld(num, payload):
        return nano_mod._enc_varint((num << 3) | 2) + nano_mod._enc_varint(len(payload)) + payload

    def vint(num, v):
        return nano_mod._enc_varint(num << 3) + nano_mod._enc_varint(v)

    dims = b"".join(ld(1, vint(1, d)) for d in (1, 3, 255, 255))
    tensor = vint(1, 1) + ld(2, dims)
    value_info = ld(1, b"input") + ld(2, ld(1, tensor))
    model = vint(1, 8) + ld(7, ld(11, value_info) + ld(13, value_info))
    relaxed = relax_spatial_dims(model)
    top = nano_mod._fields(relaxed)
    assert top[0] == (1, 0, b"\x08")                      # ir_version untouched
    graph = nano_mod._fields(top[1][2])
    assert [g[0] for g in graph] == [11]                   # value_info dropped
    vi = nano_mod._fields(graph[0][2])
    shape = nano_mod._fields(nano_mod._fields(nano_mod._fields(vi[1][2])[0][2])[1][2])
    kinds = [nano_mod._fields(d[2])[0] for d in shape]
    assert kinds[:2] == [(1, 0, b"\x01"), (1, 0, b"\x03")]
    assert kinds[2] == (2, 2, b"in_2") and kinds[3] == (2, 2, b"in_3")
    assert nano_mod._varint(nano_mod._enc_varint(300), 0) == (300, 2)


# --- with real data -------------------------------------------------------------------------

def test_relaxed_backbone_embeds_the_exemplar(models):
    import onnxruntime as ort

    path = nano_mod.relaxed_copy(resolve_model("nanotrack_backbone", None))
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    out = session.run(None, {"input": np.zeros((1, 3, 127, 127), np.float32)})[0]
    assert out.shape == (1, 48, 8, 8)
    net = cv2.dnn.readNet(str(resolve_model("nanotrack_backbone", None)))   # OpenCV reshapes itself
    x = np.random.default_rng(0).uniform(0, 255, (1, 3, 127, 127)).astype(np.float32)
    net.setInput(x)
    ref = net.forward()
    ours = session.run(None, {"input": x})[0]
    assert np.abs(ours - ref).max() < 1e-3 * np.abs(ref).max()


# OpenCV 5.1 changed both trackers (the blob scale and the box's bounds in TrackerVit; the
# search side, the size sum and the scale penalty in TrackerNano): each of ours reproduces either
# release (``opencv_port``). The installed cv2 is compared live with its port; the default port,
# 5.0, also with boxes recorded from OpenCV 5.0 (tests/opencv_tracker_reference.py).
INSTALLED_PORT = installed_opencv_port()
REFERENCE_5_0 = Path(__file__).parent / "data" / "opencv50_trackers.npz"
TRACKERS = {"vittrack": (VitTrack, cv2_vit), "nanotrack": (NanoTrack, cv2_nano)}
PARITY_SEQUENCES = {"vittrack": [("uav123_10fps/wakeboard10", 60), ("vot15_bag", 40)],
                    "nanotrack": [("uav123_10fps/wakeboard7", 40), ("otb_Couple", 40)]}
PARITY_CASES = [(name, seq, limit) for name, cases in PARITY_SEQUENCES.items() for seq, limit in cases]


@pytest.mark.parametrize("name,seq,limit", PARITY_CASES)
def test_parity_with_the_installed_opencv(models, name, seq, limit):
    cls, make = TRACKERS[name]
    frames, gt = load_sequence(models / "sequences" / seq, limit)
    ours, ref, outs = run_pair(cls(cls.Params(opencv_port=INSTALLED_PORT)), make(models), frames, gt[0])
    assert iou_rows(ours, ref).mean() >= 0.95
    for out in outs:
        assert 0.0 <= out.confidence <= 1.0 and out.score_map.shape == (16, 16)


@pytest.mark.parametrize("name", ["vittrack", "nanotrack"])
def test_parity_at_the_image_borders(models, name):
    """otb_Couple's first frames moved (reflected border) so that the 25x62 px target straddles
    each image border, or nearly touches it: cv2 5.1's TrackerVit cuts its box to the image and
    moves a 10 px side back inside, which the sequences above never reach."""
    cls, make = TRACKERS[name]
    frames, gt = load_sequence(models / "sequences" / "otb_Couple", 6)
    height, width = frames[0].shape[:2]
    x, y, w, h = gt[0]
    for dx, dy in [(-x - 0.3 * w, 0), (-x + 2, 0), (width - x - 0.7 * w, 0), (width - x - w - 2, 0),
                   (0, -y - 0.3 * h), (0, height - y - 0.7 * h)]:
        shift = np.float32([[1, 0, dx], [0, 1, dy]])
        moved = [cv2.warpAffine(f, shift, (width, height), borderMode=cv2.BORDER_REFLECT) for f in frames]
        init = np.array([x + dx, y + dy, w, h])
        ours, ref, _ = run_pair(cls(cls.Params(opencv_port=INSTALLED_PORT)), make(models), moved, np.floor(init))
        assert np.array_equal(ours, ref), (dx, dy, ours, ref)


@pytest.mark.parametrize("name,seq,limit", PARITY_CASES)
def test_the_default_port_reproduces_opencv_5_0(models, name, seq, limit):
    recorded = np.load(REFERENCE_5_0)
    assert str(recorded["opencv"]).startswith("5.0.")
    cls, _ = TRACKERS[name]
    frames, gt = load_sequence(models / "sequences" / seq, limit)
    ours = cls()
    ours.initialize(frames[0], Box.from_array(gt[0]))
    outs = [ours.track(f) for f in frames[1:]]
    boxes = np.array([out.box.as_array() for out in outs])
    assert iou_rows(boxes, recorded[f"{name}/{seq}/boxes"].astype(float)).mean() >= 0.95
    if name == "vittrack":
        scores = [out.extra["tracking_score"] for out in outs]
        assert scores == pytest.approx(recorded[f"{name}/{seq}/scores"].tolist(), abs=1e-3)


def test_vittrack_tracking_score_equals_opencv(models):
    frames, gt = load_sequence(models / "sequences" / "vot15_bag", 3)
    ours, ref = VitTrack(VitTrack.Params(opencv_port=INSTALLED_PORT)), cv2_vit(models)
    ours.initialize(frames[0], Box.from_array(gt[0]))
    ref.init(frames[0], tuple(int(v) for v in gt[0]))
    for f in frames[1:]:
        out = ours.track(f)
        ref.update(f)
        assert out.extra["tracking_score"] == pytest.approx(ref.getTrackingScore(), abs=1e-3)


def test_the_two_ports_differ_where_opencv_5_1_changed_them(models):
    """The 5.0 and 5.1 ports are not the same tracker: on wakeboard10's 10x9 px target 5.1 keeps
    every side at 10 px or more, which the 5.0 port does not (its boxes shrink to 6-8 px)."""
    frames, gt = load_sequence(models / "sequences" / "uav123_10fps/wakeboard10", 15)
    sides = {}
    for port in ("5.0", "5.1"):
        ours = VitTrack(VitTrack.Params(opencv_port=port))
        ours.initialize(frames[0], Box.from_array(gt[0]))
        sides[port] = np.array([[b.w, b.h] for b in (ours.track(f).box for f in frames[1:])])
    assert sides["5.1"].min() >= 10 and sides["5.0"].min() < 10


@pytest.mark.parametrize("cls", [VitTrack, NanoTrack])
def test_prior_recovers_a_jump_beyond_the_search_region(models, cls):
    """Translate frame 2 of wakeboard10 (a 10x9 px target, search region about 40 px) by
    (+150, +90) px: without a prior the target is outside the search region; a prior at the
    new place (a few px off) finds it."""
    frames, gt = load_sequence(models / "sequences" / "uav123_10fps/wakeboard10", 3)
    shift = np.array([150.0, 90.0])
    moved = cv2.warpAffine(frames[2], np.float32([[1, 0, shift[0]], [0, 1, shift[1]]]),
                           (frames[2].shape[1], frames[2].shape[0]), borderMode=cv2.BORDER_REFLECT)
    truth = gt[2] + np.r_[shift, 0, 0]

    def run(prior):
        t = cls()
        t.initialize(frames[0], Box.from_array(gt[0]))
        t.track(frames[1])
        return t.track(moved, prior=prior)

    lost = run(None)
    found = run((truth[0] + truth[2] / 2 + 3.0, truth[1] + truth[3] / 2 - 2.0))
    assert iou_rows(lost.box.as_array()[None], truth[None])[0] == 0.0
    assert iou_rows(found.box.as_array()[None], truth[None])[0] > 0.5
    assert found.confidence > lost.confidence


def test_registered(models):
    from mata_eval.core.registry import load_registry

    trackers = load_registry().plugins["tracker"]
    assert trackers["vittrack"].cls is VitTrack and trackers["nanotrack"].cls is NanoTrack


def test_another_trackers_model_is_refused_by_the_preflight(models, tmp_path):
    """QA pass: NanoTrack's head given as VitTrack's model (or the pair swapped) passed
    `validate`, then failed every sequence with ONNX Runtime's 'required inputs are missing'."""
    from mata_eval_plugins.trackers.backends import BackendUnavailable

    m = {"vittrack": models / "models/vittrack/object_tracking_vittrack_2023sep.onnx",
         "nano_backbone": models / "models/nanotrack/v2/nanotrack_backbone_sim.onnx",
         "nano_head": models / "models/nanotrack/v2/nanotrack_head_sim.onnx"}
    with pytest.raises(BackendUnavailable, match=r"takes the inputs input1, input2, not template, search: it is not "
                                                  r"VitTrack's object_tracking_vittrack_2023sep.onnx"):
        VitTrack(VitTrack.Params(model=str(m["nano_head"]))).check()
    with pytest.raises(BackendUnavailable, match=r"it is not NanoTrack v2's backbone"):
        NanoTrack(NanoTrack.Params(backbone=str(m["nano_head"]), head=str(m["nano_backbone"]))).check()
    # QA pass: NanoTrack v3 (same input names, 15x15 maps) passed, then failed every sequence
    # at frame 1 ("cannot reshape array of size 450 into shape (2,16,16)")
    v3 = models / "models/nanotrack/v3"
    with pytest.raises(BackendUnavailable, match=r"nanotrack_head.onnx gives outputs of shape \(1, 2, 15, 15\), "
                                                  r"\(1, 4, 15, 15\), not \(1, 2, 16, 16\), \(1, 4, 16, 16\): it is "
                                                  r"not NanoTrack v2's head"):
        NanoTrack(NanoTrack.Params(backbone=str(m["nano_backbone"]), head=str(v3 / "nanotrack_head.onnx"))).check()
    with pytest.raises(BackendUnavailable, match=r"nanotrack_backbone.onnx gives outputs of shape \(1, 96, 16, 16\)"):
        NanoTrack(NanoTrack.Params(backbone=str(v3 / "nanotrack_backbone.onnx"), head=str(m["nano_head"]))).check()
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(BackendUnavailable, match=r"junk.onnx: not an ONNX model"):
        VitTrack(VitTrack.Params(model=str(tmp_path / "junk.onnx"))).check()
    VitTrack(VitTrack.Params(model=str(m["vittrack"]))).check()       # the right files pass
    NanoTrack(NanoTrack.Params(backbone=str(m["nano_backbone"]), head=str(m["nano_head"]))).check()


def test_a_run_records_its_model_file_and_refuses_results_of_another(models, tmp_path, monkeypatch):
    """The model file found through $MATA_VITTRACK_ONNX is in no YAML value: the manifest records
    its path and sha256, and a rerun with another file does not resume the old results (QA
    pass: 'finished sequence(s) kept' with another model)."""
    import hashlib
    import json
    import shutil

    import onnx

    from mata_eval.run.config import load_experiment
    from mata_eval.run.runner import ResultsConflict, run_experiment

    seq = tmp_path / "data" / "s"
    (seq / "img").mkdir(parents=True)
    src = sorted((models / "sequences" / "aerial30" / "S0601" / "img").iterdir())[:3]
    for k, p in enumerate(src):
        shutil.copy(p, seq / "img" / f"{k:04d}.jpg")
    gt = np.loadtxt(models / "sequences" / "aerial30" / "S0601" / "groundtruth_rect.txt", delimiter=",")[:3]
    np.savetxt(seq / "groundtruth_rect.txt", gt, delimiter=",")
    exp_file = tmp_path / "exp.yaml"
    exp_file.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: folder, root: {tmp_path / 'data'}}}\n"
                        "tracker: {name: vittrack}\n")
    a, b = tmp_path / "a.onnx", tmp_path / "b.onnx"
    shutil.copy(models / "models/vittrack/object_tracking_vittrack_2023sep.onnx", a)
    graph = onnx.load(str(a))
    graph.doc_string = "another build of the same graph"
    onnx.save(graph, str(b))
    monkeypatch.setenv("MATA_VITTRACK_ONNX", str(a))
    quiet = dict(jobs=1, progress=False, log=lambda s: None)
    assert [o.status for o in run_experiment(load_experiment(exp_file), **quiet)] == ["done"]
    manifest = json.loads((tmp_path / "out" / "exp" / "manifest.json").read_text())
    assert manifest["model_files"] == {"model": {"path": str(a), "sha256": hashlib.sha256(a.read_bytes()).hexdigest()}}
    assert [o.status for o in run_experiment(load_experiment(exp_file), **quiet)] == ["skipped"]
    monkeypatch.setenv("MATA_VITTRACK_ONNX", str(b))
    with pytest.raises(ResultsConflict, match=r"another model file .*a.onnx.* than .*b.onnx"):
        run_experiment(load_experiment(exp_file), **quiet)
    assert [o.status for o in run_experiment(load_experiment(exp_file), force=True, **quiet)] == ["done"]
    then, now = (hashlib.sha256(p.read_bytes()).hexdigest()[:12] for p in (b, a))
    shutil.copy(a, b)   # the same path, another content (QA pass: "another model file (b) than b")
    with pytest.raises(ResultsConflict, match=rf"another content of its model file .*b.onnx \(sha256 {then}\.\.\. "
                                              rf"then, {now}\.\.\. now\)"):
        run_experiment(load_experiment(exp_file), **quiet)
