"""``mata-eval export``: tiny random-weight MixFormerV2/OSTrack and NanoTrack v2 to ONNX, with
parity against torch (inside export and here, on fresh inputs), the two-graph MixFormerV2 chain
against the full torch forward, no data-dependent ops in OSTrack, and the .pth export against the
published NanoTrack ONNX pair."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnx", reason="torch.onnx.export needs the onnx package (pip install onnx)")

from mata_eval.cli import build_parser
from mata_eval.deploy import export as E  # noqa: E402
from mata_eval_plugins.trackers import vit  # noqa: E402

TINY_MF = vit.MixFormerV2Config(template_size=32, search_size=64, depth=2, embed_dim=64, num_heads=4, feat_sz=16)
TINY_OS = vit.OSTrackConfig(template_size=32, search_size=64, depth=3, embed_dim=64, num_heads=4, ce_loc=(1,),
                            ce_keep_ratio=(0.7,), head_channels=32, pretrain_grid=2)


def _session(path):
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


@pytest.fixture(scope="module")
def mixformer(tmp_path_factory):
    torch.manual_seed(1)
    net = vit.MixFormerV2Net(TINY_MF).eval()
    out = tmp_path_factory.mktemp("mf")
    return net, E.export_mixformerv2(out, network=net, prefix="tiny", seed=1)


def test_mixformer_full_graph_has_the_four_pmfs_and_matches_torch(mixformer):
    net, result = mixformer
    g = result.graph("full")
    assert g.outputs == ("box", "score_logit", "pmf_left", "pmf_top", "pmf_right", "pmf_bottom")
    rng = np.random.default_rng(42)
    z, oz = (rng.standard_normal((1, 3, 32, 32)).astype(np.float32) for _ in range(2))
    x = rng.standard_normal((1, 3, 64, 64)).astype(np.float32)
    out = dict(zip(g.outputs, _session(g.path).run(None, {"template": z, "online_template": oz, "search": x})))
    with torch.no_grad():
        box, logit, pmfs = net(torch.from_numpy(z), torch.from_numpy(oz), torch.from_numpy(x))
    for i, side in enumerate(("left", "top", "right", "bottom")):
        pmf = out[f"pmf_{side}"]
        assert pmf.shape == (1, 16)
        assert pmf.sum() == pytest.approx(1.0, abs=1e-5)        # each output is a PMF
        np.testing.assert_allclose(pmf, pmfs[:, i].numpy(), atol=1e-5)
    np.testing.assert_allclose(out["box"], box.numpy(), atol=1e-5)
    np.testing.assert_allclose(out["score_logit"], logit.numpy(), atol=1e-5)
    # The box is the PMF expectation (independent recomputation): x1 = E[left] / N, ...
    bins = np.arange(16)
    l, t, r, b = ((out[f"pmf_{s}"][0] * bins).sum() / 16 for s in ("left", "top", "right", "bottom"))
    np.testing.assert_allclose(out["box"][0], [(l + r) / 2, (t + b) / 2, r - l, b - t], atol=1e-5)


def test_mixformer_two_graph_chain_equals_full_forward(mixformer):
    net, result = mixformer
    tg, sg = result.graph("template"), result.graph("search")
    assert tg.outputs == ("key_0", "value_0", "key_1", "value_1")
    assert sg.inputs == ("search",) + tg.outputs
    rng = np.random.default_rng(7)
    z, oz = (rng.standard_normal((1, 3, 32, 32)).astype(np.float32) for _ in range(2))
    kv = _session(tg.path).run(None, {"template": z, "online_template": oz})
    assert kv[0].shape == (1, 4, 2 * 4, 16)   # (B, heads, 2 Lt, d): Lt = (32/16)^2 = 4
    search = _session(sg.path)
    for _ in range(2):   # the cached template serves several search frames
        x = rng.standard_normal((1, 3, 64, 64)).astype(np.float32)
        got = search.run(None, {"search": x, **dict(zip(tg.outputs, kv))})
        with torch.no_grad():
            box, logit, pmfs = net(torch.from_numpy(z), torch.from_numpy(oz), torch.from_numpy(x))
        np.testing.assert_allclose(got[0], box.numpy(), atol=1e-5)
        np.testing.assert_allclose(np.stack(got[2:], axis=1), pmfs.numpy(), atol=1e-5)
    doc = json.loads((result.out_dir / "export.json").read_text())
    assert doc["model"] == "mixformerv2" and doc["config"]["depth"] == 2
    assert doc["graphs"]["search"]["file"] == "tiny_search.onnx"


def test_ostrack_graph_matches_torch_without_data_dependent_ops(tmp_path):
    torch.manual_seed(2)
    net = vit.OSTrackNet(TINY_OS).eval()
    result = E.export_ostrack(tmp_path, network=net, name="tiny", seed=2)
    ops = E.graph_op_types(result.graph("full").path)
    assert "NonZero" not in ops and "TopK" in ops        # CE is in the graph, by constant indices
    rng = np.random.default_rng(3)
    z = rng.standard_normal((1, 3, 32, 32)).astype(np.float32)
    x = rng.standard_normal((1, 3, 64, 64)).astype(np.float32)
    got = _session(result.graph("full").path).run(None, {"template": z, "search": x})
    with torch.no_grad():
        ref = net(torch.from_numpy(z), torch.from_numpy(x))
    assert len(net.removed_indexes) == 1 and net.removed_indexes[0].shape[1] == 16 - 12   # ceil(0.7 * 16) kept
    for g, r in zip(got, ref):
        np.testing.assert_allclose(g, r.numpy(), atol=1e-5)


def test_parity_failure_is_loud_and_leaves_no_file(tmp_path):
    class Branchy(torch.nn.Module):
        """Tracing freezes the Python branch taken on the example: the graph is wrong elsewhere."""

        def forward(self, x):
            return x * 2 if float(x.sum()) > 0 else x * 3

    pos = {"x": np.ones((1, 4), np.float32)}
    with pytest.raises(E.ParityError, match="differs from torch"), E._pending_removed_on_failure(tmp_path):
        E._export_checked("full", Branchy(), pos, [{"x": -np.ones((1, 4), np.float32)}], tmp_path / "b.onnx",
                          ["x"], ["y"])
    assert not (tmp_path / "b.onnx").exists()
    # over an earlier export: that one stays whole (QA pass 13: the failed re-export deleted its graph)
    (tmp_path / "b.onnx").write_bytes(b"the earlier, checked graph")
    with pytest.raises(E.ParityError, match="differs from torch") as err:
        with E._pending_removed_on_failure(tmp_path):
            E._export_checked("full", Branchy(), pos, [{"x": -np.ones((1, 4), np.float32)}], tmp_path / "b.onnx",
                              ["x"], ["y"])
    assert str(err.value).startswith(f"{tmp_path / 'b.onnx'}: output 'y'")   # the name the user knows
    assert (tmp_path / "b.onnx").read_bytes() == b"the earlier, checked graph"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.onnx"]


@pytest.mark.parametrize("failure", [E.ParityError("the chain differs"), KeyboardInterrupt()])
def test_a_failed_or_interrupted_two_graph_export_leaves_the_earlier_export_whole(tmp_path, monkeypatch, failure):
    """Review: the template and search graphs were checked, then the chain check failed (or
    Ctrl-C came): both stayed in the folder as .pending-* files."""
    torch.manual_seed(1)
    E.export_mixformerv2(tmp_path, network=vit.MixFormerV2Net(TINY_MF).eval(), prefix="tiny", forms=("two_graph",))
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def fail(*args, **kwargs):
        raise failure

    monkeypatch.setattr(E, "_check_chain", fail)
    torch.manual_seed(2)   # other weights: a graph replaced would show
    with pytest.raises(type(failure)):
        E.export_mixformerv2(tmp_path, network=vit.MixFormerV2Net(TINY_MF).eval(), prefix="tiny", forms=("two_graph",))
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_nanotrack_random_weights_through_the_cli(tmp_path, capsys):
    parser = build_parser()
    args = parser.parse_args(["export", "nanotrack", "--random-weights", "--seed", "5", "--out", str(tmp_path)])
    assert args.func(args) == 0
    printed = capsys.readouterr().out
    assert "max |onnxruntime - torch|" in printed
    bb = _session(tmp_path / "nanotrack_backbone_sim.onnx")
    # One graph serves both crop sizes (free spatial dims), as the tracker needs.
    assert bb.run(None, {"input": np.zeros((1, 3, 127, 127), np.float32)})[0].shape == (1, 48, 8, 8)
    assert bb.run(None, {"input": np.zeros((1, 3, 255, 255), np.float32)})[0].shape == (1, 48, 16, 16)
    args = parser.parse_args(["export", "nanotrack", "--out", str(tmp_path)])
    assert args.func(args) == 2 and "--random-weights" in capsys.readouterr().err
    args = parser.parse_args(["export", "nanotrack", "--random-weights", "--checkpoint", "x.pth", "--out", str(tmp_path)])
    assert args.func(args) == 2 and "not both" in capsys.readouterr().err   # one of them was silently ignored
    args = parser.parse_args(["export", "nanotrack", "--random-weights", "--variant", "B", "--out", str(tmp_path)])
    assert args.func(args) == 2 and "--variant and --form are MixFormerV2's" in capsys.readouterr().err


def test_nanotrack_from_pth_matches_the_published_pair_and_tracks(shared_data, tmp_path):
    from mata_eval.types import Box
    from mata_eval_plugins.trackers.nanotrack import NanoTrack, relaxed_copy

    pth = shared_data / "models/nanotrack/pth/nanotrackv2.pth"
    result = E.export_nanotrack(tmp_path, pth.parent)   # the folder holding it (review: "Is a directory")
    assert json.loads((tmp_path / "export.json").read_text())["checkpoint"] == str(pth)
    ref_bb = _session(relaxed_copy(shared_data / "models/nanotrack/v2/nanotrack_backbone_sim.onnx"))
    ref_hd = _session(shared_data / "models/nanotrack/v2/nanotrack_head_sim.onnx")
    bb, hd = _session(result.graph("backbone").path), _session(result.graph("head").path)
    rng = np.random.default_rng(11)
    z = rng.uniform(0, 255, (1, 3, 127, 127)).astype(np.float32)
    x = rng.uniform(0, 255, (1, 3, 255, 255)).astype(np.float32)
    zf, xf = bb.run(None, {"input": z})[0], bb.run(None, {"input": x})[0]
    np.testing.assert_allclose(zf, ref_bb.run(None, {"input": z})[0], atol=1e-4, rtol=1e-4)
    np.testing.assert_allclose(xf, ref_bb.run(None, {"input": x})[0], atol=1e-4, rtol=1e-4)
    for a, b in zip(hd.run(None, {"input1": zf, "input2": xf}), ref_hd.run(None, {"input1": zf, "input2": xf})):
        np.testing.assert_allclose(a, b, atol=1e-3, rtol=1e-4)
    # The nanotrack tracker loads the exported folder and follows the published pair's boxes.
    frames = [np.full((120, 160, 3), 90, np.uint8) for _ in range(4)]
    for k, f in enumerate(frames):
        f[40 + 2 * k:70 + 2 * k, 50 + 3 * k:80 + 3 * k] = (30, 200, 240)
    ours = NanoTrack(NanoTrack.Params(backbone=str(tmp_path), head=str(tmp_path)))
    ref = NanoTrack(NanoTrack.Params(backbone=str(shared_data / "models/nanotrack/v2"),
                                     head=str(shared_data / "models/nanotrack/v2")))
    for t in (ours, ref):
        t.initialize(frames[0], Box(50, 40, 30, 30))
    for f in frames[1:]:
        a, b = ours.track(f), ref.track(f)
        np.testing.assert_allclose(a.box.as_array(), b.box.as_array(), atol=1.0)
        assert a.confidence == pytest.approx(b.confidence, abs=1e-3)


def test_a_missing_export_package_is_named_with_what_to_install(monkeypatch):
    """QA pass: without onnx the advice was `pip install torch onnx onnxruntime`, and a plain
    `pip install torch` is the wrong advice on a Jetson."""
    import sys

    monkeypatch.setitem(sys.modules, "onnx", None)
    with pytest.raises(RuntimeError, match=r"\(onnx is missing\): pip install onnx$"):
        E._require_export_stack()
