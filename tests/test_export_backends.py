"""Backends selectable per tracker: MixFormerV2 and OSTrack on the graphs of ``mata-eval export``
through ONNX Runtime follow their torch trackers frame by frame (same boxes, confidences and
template updates); a wrong setup names what is missing; TensorRT is skipped where absent."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnx", reason="torch.onnx.export needs the onnx package (pip install onnx)")

from mata_eval.deploy import export as E  # noqa: E402
from mata_eval.types import Box  # noqa: E402
from mata_eval_plugins.trackers import vit  # noqa: E402
from mata_eval_plugins.trackers.mixformerv2 import MixFormerV2  # noqa: E402
from mata_eval_plugins.trackers.ostrack import OSTrack  # noqa: E402

from test_export import TINY_MF, TINY_OS  # noqa: E402


def _frames(n=6, seed=0):
    """A textured background with a bright square moving 3 px right and 2 px down per frame."""
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 255, (96, 128, 3), dtype=np.uint8)
    out = []
    for k in range(n):
        f = base.copy()
        f[30 + 2 * k:50 + 2 * k, 40 + 3 * k:60 + 3 * k] = (20, 220, 250)
        out.append(f)
    return out


@pytest.mark.parametrize("template_cache", [True, False])
def test_mixformerv2_onnxruntime_follows_torch(tmp_path, template_cache):
    torch.manual_seed(4)
    net = vit.MixFormerV2Net(TINY_MF).eval()
    E.export_mixformerv2(tmp_path, network=net, seed=4)
    common = dict(template_cache=template_cache, tau_template=0.0)   # update the template every frame
    ref = MixFormerV2(MixFormerV2.Params(**common), network=net)
    onnx = MixFormerV2(MixFormerV2.Params(backend="onnxruntime", onnx=str(tmp_path), **common))
    frames = _frames()
    for t in (ref, onnx):
        t.initialize(frames[0], Box(40, 30, 20, 20))
    for f in frames[1:]:
        a, b = ref.track(f), onnx.track(f, prior=None)
        np.testing.assert_allclose(b.box.as_array(), a.box.as_array(), atol=1e-3)
        assert b.confidence == pytest.approx(a.confidence, abs=1e-5)
        np.testing.assert_allclose(b.pmfs, a.pmfs, atol=1e-5)
        assert b.extra["template_updated"] == a.extra["template_updated"] == 1.0


def test_ostrack_onnxruntime_follows_torch(tmp_path):
    torch.manual_seed(5)
    net = vit.OSTrackNet(TINY_OS).eval()
    E.export_ostrack(tmp_path, network=net, seed=5)
    ref = OSTrack(OSTrack.Params(), network=net)
    onnx = OSTrack(OSTrack.Params(backend="onnxruntime", onnx=str(tmp_path)))
    frames = _frames(seed=1)
    for t in (ref, onnx):
        t.initialize(frames[0], Box(40, 30, 20, 20))
    for k, f in enumerate(frames[1:]):
        prior = (52.0 + k, 42.0) if k % 2 else None      # the MATA prior moves the search region
        a, b = ref.track(f, prior), onnx.track(f, prior)
        np.testing.assert_allclose(b.box.as_array(), a.box.as_array(), atol=1e-3)
        assert b.confidence == pytest.approx(a.confidence, abs=1e-5)
    # CE is baked into the graph: another keep ratio is refused when the tracker is built (the
    # preflight), not in every sequence's first frame (QA pass)
    with pytest.raises(ValueError, match=r"export.json: the exported graph eliminates candidates at keep ratio 0.7 \(fixed in the graph\), but the tracker says "
                                         r"ce_keep_ratio: 1.0; set ce_keep_ratio: null or backend: torch"):
        OSTrack(OSTrack.Params(backend="onnxruntime", onnx=str(tmp_path), ce_keep_ratio=1.0))
    OSTrack(OSTrack.Params(backend="onnxruntime", onnx=str(tmp_path), ce_keep_ratio=0.7))   # the exported one


def test_backend_setup_errors_name_what_is_missing(tmp_path):
    with pytest.raises(ValueError, match="needs `onnx`"):
        MixFormerV2(MixFormerV2.Params(backend="onnxruntime"))
    # an export of another variant is refused when the tracker is built (the preflight), not
    # run with the wrong crop sizes (QA pass: variant B on an export of S ran, SR 17.1)
    torch.manual_seed(4)
    E.export_mixformerv2(tmp_path / "s", network=vit.MixFormerV2Net(TINY_MF).eval(), seed=4, variant="S")
    with pytest.raises(ValueError, match=r"export.json: an export of variant S, but the tracker says variant: B"):
        MixFormerV2(MixFormerV2.Params(backend="onnxruntime", onnx=str(tmp_path / "s"), variant="B"))
    with pytest.raises(FileNotFoundError, match="export.json not found.*mata-eval export mixformerv2"):
        MixFormerV2(MixFormerV2.Params(backend="onnxruntime", onnx=str(tmp_path / "none")))
    with pytest.raises(FileNotFoundError, match="export.json not found.*mata-eval export ostrack"):
        OSTrack(OSTrack.Params(backend="onnxruntime", onnx=str(tmp_path)))
    # OSTrack on a MixFormerV2 export, and the cache on an export without its two graphs, are
    # refused when the tracker is built (QA pass: both failed in every sequence's first frame)
    with pytest.raises(ValueError, match=r"s/export.json: expected a mata-eval export of 'ostrack', got model 'mixformerv2'"):
        OSTrack(OSTrack.Params(backend="onnxruntime", onnx=str(tmp_path / "s")))
    E.export_mixformerv2(tmp_path / "full", network=vit.MixFormerV2Net(TINY_MF).eval(), seed=4, forms=("full",))
    with pytest.raises(ValueError, match=r"full/export.json: template_cache: true runs the template and search graph\(s\), "
                                         r"but this export has full; set template_cache: false or export them "
                                         r"\(mata-eval export mixformerv2 --form two-graph or both\)"):
        MixFormerV2(MixFormerV2.Params(backend="onnxruntime", onnx=str(tmp_path / "full")))
    full = MixFormerV2(MixFormerV2.Params(backend="onnxruntime", onnx=str(tmp_path / "full"), template_cache=False))
    full.check()
    # a graph export.json lists, deleted or cut short: named by the preflight (QA pass 13: it passed)
    from mata_eval_plugins.trackers.backends import BackendUnavailable

    graph = next((tmp_path / "full").glob("*.onnx"))
    graph.write_bytes(graph.read_bytes()[:100])
    with pytest.raises(BackendUnavailable, match=rf"{graph.name}: not an ONNX model ONNX Runtime can read"):
        full.check()
    graph.unlink()
    with pytest.raises(BackendUnavailable, match=rf"{graph.name}: the full graph export.json lists is missing"):
        full.check()


def test_tensorrt_backend_is_skipped_or_explains(tmp_path):
    if importlib.util.find_spec("tensorrt") is None:
        from mata_eval_plugins.trackers.backends import BackendUnavailable

        torch.manual_seed(6)
        E.export_ostrack(tmp_path, network=vit.OSTrackNet(TINY_OS).eval(), seed=6)
        t = OSTrack(OSTrack.Params(backend="tensorrt", onnx=str(tmp_path)))
        with pytest.raises(BackendUnavailable, match="TensorRT is not installed"):
            t.initialize(_frames(1)[0], Box(40, 30, 20, 20))
        pytest.skip("TensorRT is not installed here: engine build and run not exercised")
    if not torch.cuda.is_available():
        pytest.skip("TensorRT is installed but no CUDA device is visible")
    torch.manual_seed(6)
    net = vit.OSTrackNet(TINY_OS).eval()
    E.export_ostrack(tmp_path, network=net, seed=6)
    ref = OSTrack(OSTrack.Params(), network=net)
    trt = OSTrack(OSTrack.Params(backend="tensorrt", onnx=str(tmp_path)))
    frames = _frames(seed=2)
    for t in (ref, trt):
        t.initialize(frames[0], Box(40, 30, 20, 20))
    a, b = ref.track(frames[1]), trt.track(frames[1])
    np.testing.assert_allclose(b.box.as_array(), a.box.as_array(), atol=0.5)


def test_the_preflight_checks_the_torch_device(monkeypatch, tmp_path):
    """QA pass: `device: cuda` on a torch without CUDA, or `device: foo`, passed `validate` and
    failed every sequence with torch's own error."""
    from mata_eval_plugins.trackers.backends import BackendUnavailable

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for cls in (MixFormerV2, OSTrack):
        cls(cls.Params(random_weights=True)).check()                    # cpu: fine
        with pytest.raises(BackendUnavailable, match=r"device 'cuda', but this torch .* has no CUDA device"):
            cls(cls.Params(random_weights=True, device="cuda")).check()
        with pytest.raises(BackendUnavailable, match=r"device 'foo' is not a torch device"):
            cls(cls.Params(random_weights=True, device="foo")).check()
        with pytest.raises(BackendUnavailable, match=r"the torch backend runs on cpu or cuda"):
            cls(cls.Params(random_weights=True, device="meta")).check()


def test_model_files_are_the_graphs_of_the_export(tmp_path):
    """A run on an export records its graph files (the manifest's model_files), as a run on a
    checkpoint records the checkpoint."""
    torch.manual_seed(4)
    E.export_mixformerv2(tmp_path / "mf", network=vit.MixFormerV2Net(TINY_MF).eval(), prefix="tiny", seed=4)
    E.export_ostrack(tmp_path / "os", network=vit.OSTrackNet(TINY_OS).eval(), name="tiny", seed=4)
    mf = MixFormerV2.model_files(MixFormerV2.Params(backend="onnxruntime", onnx=str(tmp_path / "mf")))
    assert mf == {f"onnx_{role}": tmp_path / "mf" / f"tiny{end}.onnx"
                  for role, end in (("full", ""), ("template", "_template"), ("search", "_search"))}
    assert OSTrack.model_files(OSTrack.Params(backend="onnxruntime", onnx=str(tmp_path / "os"))) == {
        "onnx_full": tmp_path / "os" / "tiny.onnx"}


def test_a_run_on_another_models_export_fails_its_sequences_not_the_experiment(tmp_path):
    """Recording the model files read (manifest.json) must not stop the experiment when an
    export.json is of another model: that run's sequences fail with the reason, the others run."""
    import cv2

    from mata_eval.run.config import load_experiment
    from mata_eval.run.runner import run_experiment

    torch.manual_seed(4)
    E.export_mixformerv2(tmp_path / "mf", network=vit.MixFormerV2Net(TINY_MF).eval(), seed=4)
    seq = tmp_path / "data" / "s" / "img"
    seq.mkdir(parents=True)
    for k, f in enumerate(_frames(3)):
        cv2.imwrite(str(seq / f"{k:04d}.png"), f)
    (seq.parent / "groundtruth_rect.txt").write_text("".join(f"{40 + 3 * k},{30 + 2 * k},20,20\n" for k in range(3)))
    exp_file = tmp_path / "exp.yaml"
    exp_file.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: folder, root: {tmp_path / 'data'}}}\n"
                        "tracker: {name: kcf}\nmatrix:\n  tracker:\n    kcf: {}\n"
                        f"    os: {{name: ostrack, backend: onnxruntime, onnx: {tmp_path / 'mf'}}}\n")
    outcomes = run_experiment(load_experiment(exp_file), jobs=1, progress=False, log=lambda s: None)
    assert {o.run: o.status for o in outcomes} == {"kcf": "done", "os": "failed"}
    assert "expected a mata-eval export of 'ostrack', got model 'mixformerv2'" in next(o.reason for o in outcomes
                                                                                       if o.run == "os")


def test_export_reads_the_checkpoint_as_the_tracker_does(tmp_path, monkeypatch, capsys):
    """QA pass 13: export --checkpoint took neither the folder holding the official file nor the
    tracker's environment variable (the tracker's checkpoint: takes both), and export.json held
    no sha256 of the checkpoint for MixFormerV2 and OSTrack."""
    import hashlib
    import json

    from mata_eval.cli import build_parser

    torch.manual_seed(3)
    ck = tmp_path / "ck" / "OSTrack_ep0300.pth.tar"
    ck.parent.mkdir()
    torch.save({"net": vit.OSTrackNet(TINY_OS).state_dict()}, ck)
    monkeypatch.setattr(vit, "OSTRACK_256", TINY_OS)   # the tiny network stands for the official one
    parser = build_parser()
    args = parser.parse_args(["export", "ostrack", "--checkpoint", str(ck.parent), "--out", str(tmp_path / "a")])
    assert args.func(args) == 0
    doc = json.loads((tmp_path / "a" / "export.json").read_text())
    assert doc["checkpoint"] == str(ck) and doc["checkpoint_sha256"] == hashlib.sha256(ck.read_bytes()).hexdigest()
    monkeypatch.setenv("MATA_OSTRACK", str(ck))
    args = parser.parse_args(["export", "ostrack", "--out", str(tmp_path / "b")])
    assert args.func(args) == 0 and json.loads((tmp_path / "b" / "export.json").read_text())["checkpoint"] == str(ck)


def test_a_gpu_device_without_the_gpu_onnxruntime_says_what_to_install():
    """QA pass 14: the error named the missing provider and stopped there."""
    ort = pytest.importorskip("onnxruntime")
    from mata_eval_plugins.trackers.backends import BackendUnavailable, check_backend

    if "CUDAExecutionProvider" in ort.get_available_providers():
        pytest.skip("this onnxruntime has CUDA")
    with pytest.raises(BackendUnavailable, match=r"device 'cuda' needs CUDAExecutionProvider, but this onnxruntime "
                                                 r"offers only .*: install onnxruntime-gpu .* or use device: cpu"):
        check_backend("onnxruntime", "cuda")
