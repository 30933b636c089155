"""NanoTrack v2 in PyTorch: the published checkpoint loads strictly (weights only), and the
network reproduces the published ONNX pair (an independent artefact of the same weights) on
random crops."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
ort = pytest.importorskip("onnxruntime")

from mata_eval_plugins.trackers import nanotrack_torch as nt  # noqa: E402


@pytest.fixture(scope="module")
def paths(shared_data):
    return {"pth": shared_data / "models/nanotrack/pth/nanotrackv2.pth",
            "backbone": shared_data / "models/nanotrack/v2/nanotrack_backbone_sim.onnx",
            "head": shared_data / "models/nanotrack/v2/nanotrack_head_sim.onnx"}


def test_architecture_matches_checkpoint_keys_and_shapes(paths):
    sd = nt.read_checkpoint(paths["pth"])
    assert len(sd) == 298
    own = nt.NanoTrackV2().state_dict()
    assert set(own) == set(sd)
    assert all(own[k].shape == sd[k].shape for k in own)


def test_plain_weights_only_load_refuses_the_numpy_pickle(paths):
    # The reason the loader allows numpy scalars/dtypes explicitly: a bare weights_only load fails.
    import pickle

    with pytest.raises(pickle.UnpicklingError):
        torch.load(paths["pth"], map_location="cpu", weights_only=True)


def test_outputs_equal_the_published_onnx_pair(paths):
    from mata_eval_plugins.trackers.nanotrack import relaxed_copy

    model = nt.load_nanotrack_v2(paths["pth"])
    backbone = ort.InferenceSession(str(relaxed_copy(paths["backbone"])), providers=["CPUExecutionProvider"])
    head = ort.InferenceSession(str(paths["head"]), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    for _ in range(2):
        z = rng.uniform(0, 255, (1, 3, 127, 127)).astype(np.float32)
        x = rng.uniform(0, 255, (1, 3, 255, 255)).astype(np.float32)
        with torch.no_grad():
            zf, xf = model.backbone(torch.from_numpy(z)), model.backbone(torch.from_numpy(x))
            cls, loc = model.ban_head(zf, xf)
        ozf = backbone.run(None, {"input": z})[0]
        oxf = backbone.run(None, {"input": x})[0]
        assert ozf.shape == (1, 48, 8, 8) and oxf.shape == (1, 48, 16, 16)
        np.testing.assert_allclose(zf.numpy(), ozf, atol=1e-4, rtol=1e-4)
        np.testing.assert_allclose(xf.numpy(), oxf, atol=1e-4, rtol=1e-4)
        ocls, oloc = head.run(["output1", "output2"], {"input1": ozf, "input2": oxf})
        np.testing.assert_allclose(cls.numpy(), ocls, atol=1e-4, rtol=1e-4)
        np.testing.assert_allclose(loc.numpy(), oloc, atol=1e-3, rtol=1e-4)   # exp(): values up to ~60


def test_wrong_file_is_named(tmp_path):
    bad = tmp_path / "other.pth"
    torch.save({"state_dict": {"backbone.features.0.0.weight": torch.zeros(1)}}, bad)
    with pytest.raises(ValueError, match="other.pth is not a NanoTrack v2 checkpoint"):
        nt.load_nanotrack_v2(bad)
    with pytest.raises(FileNotFoundError, match="missing.pth"):
        nt.load_nanotrack_v2(tmp_path / "missing.pth")



def test_an_onnx_graph_or_a_folder_as_the_checkpoint(paths):
    """QA pass 14: an ONNX graph given as the checkpoint was told to retry with --trust-pickle,
    also when it had; the folder holding nanotrackv2.pth was "not found"."""
    for trust in (False, True):
        with pytest.raises(ValueError, match=r"nanotrack_backbone_sim.onnx: not a PyTorch checkpoint \(.*\); expected "
                                             r"nanotrackv2.pth from .* named as the nanotrack tracker's backbone: and head:"):
            nt.read_checkpoint(paths["backbone"], trust_pickle=trust)
    assert len(nt.read_checkpoint(paths["pth"].parent)) == 298



def test_a_checkpoint_with_python_objects_is_told_about_trust_pickle(tmp_path):
    """Review: the hint was chosen on the error's first line, which torch 2.13 fills with
    "Weights only load failed": a real pickled checkpoint was called "not a PyTorch checkpoint"."""
    import argparse

    path = tmp_path / "legacy.pth"
    torch.save({"state_dict": nt.NanoTrackV2().state_dict(), "args": argparse.Namespace(lr=0.1)}, path)
    with pytest.raises(ValueError, match=r"legacy.pth: weights-only loading refused the file \(.*Unsupported global: "
                                         r"GLOBAL argparse.Namespace.*\); if you trust it, .* --trust-pickle"):
        nt.read_checkpoint(path)
    assert len(nt.read_checkpoint(path, trust_pickle=True)) == 298


def test_random_weights_are_seeded():
    a = nt.init_random(nt.NanoTrackV2(), seed=3).state_dict()
    b = nt.init_random(nt.NanoTrackV2(), seed=3).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_nanotrack_tracker_on_the_torch_backend_follows_the_published_onnx(paths):
    from mata_eval.types import Box
    from mata_eval_plugins.trackers.nanotrack import NanoTrack

    rng = np.random.default_rng(2)
    base = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    frames = []
    for k in range(5):
        f = base.copy()
        f[40 + 2 * k:70 + 2 * k, 50 + 3 * k:80 + 3 * k] = (30, 200, 240)
        frames.append(f)
    on_torch = NanoTrack(NanoTrack.Params(backend="torch", checkpoint=str(paths["pth"])))
    on_onnx = NanoTrack(NanoTrack.Params(backbone=str(paths["backbone"]), head=str(paths["head"])))
    for t in (on_torch, on_onnx):
        t.initialize(frames[0], Box(50, 40, 30, 30))
    for f in frames[1:]:
        a, b = on_torch.track(f), on_onnx.track(f)
        np.testing.assert_allclose(a.box.as_array(), b.box.as_array(), atol=1.0)
        assert a.confidence == pytest.approx(b.confidence, abs=1e-3)
    with pytest.raises(ValueError, match="needs `checkpoint`"):
        NanoTrack(NanoTrack.Params(backend="torch"))


def test_the_torch_backend_takes_its_device_and_checks_it_before_the_run(paths, tmp_path, monkeypatch):
    """QA pass: ``device: cuda`` ran on the CPU without a word (the device never reached torch),
    and a missing checkpoint passed the preflight. The model now moves to the device, and the
    preflight refuses what cannot run here."""
    import torch

    from mata_eval_plugins.trackers.backends import BackendUnavailable
    from mata_eval_plugins.trackers.nanotrack import NanoTrack
    from mata_eval_plugins.trackers import nanotrack_torch

    seen = []
    real = nanotrack_torch.load_nanotrack_v2

    class Spy(torch.nn.Module):
        def to(self, device):
            seen.append(device)
            return self

    monkeypatch.setattr(nanotrack_torch, "load_nanotrack_v2", lambda path, trust=False: Spy())
    nanotrack_torch.torch_runners(paths["pth"], device="cuda")
    assert seen == ["cuda"]
    monkeypatch.setattr(nanotrack_torch, "load_nanotrack_v2", real)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(BackendUnavailable, match=r"device 'cuda', but this torch .* has no CUDA device"):
        NanoTrack(NanoTrack.Params(backend="torch", checkpoint=str(paths["pth"]), device="cuda")).check()
    with pytest.raises(BackendUnavailable, match="device 'tensorrt' is not a torch device"):
        NanoTrack(NanoTrack.Params(backend="torch", checkpoint=str(paths["pth"]), device="tensorrt")).check()
    with pytest.raises(BackendUnavailable, match="checkpoint not found: .*expected nanotrackv2.pth from"):
        NanoTrack(NanoTrack.Params(backend="torch", checkpoint=str(tmp_path / "no.pth"))).check()
    NanoTrack(NanoTrack.Params(backend="torch", checkpoint=str(paths["pth"]))).check()   # cpu: fine
