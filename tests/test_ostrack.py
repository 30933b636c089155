"""OSTrack (vitb_256_mae_ce) in PyTorch: the official state_dict layout (MODELS.md 2.5, every key
and shape, the published parameter count), candidate elimination (keep 0.7 at blocks 3, 6, 9:
256 -> 180 -> 126 -> 89 search tokens), the centre-head box and Hann window against hand-computed
values, a checkpoint round trip with BatchNorm buffers, and the tracker on a tiny network."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from mata_eval.types import Box  # noqa: E402
from mata_eval_plugins.trackers import vit  # noqa: E402
from mata_eval_plugins.trackers.ostrack import OSTrack, center_head_box, hann_window_2d  # noqa: E402

# the real token layout (template 8 x 8, search 16 x 16, 12 blocks, CE at 3, 6, 9) at a tiny width
TINY = vit.OSTrackConfig(embed_dim=16, num_heads=2, mlp_ratio=2.0, head_channels=16, pretrain_grid=2)


def documented_layout(d: int = 768, c: int = 256) -> dict:
    """Key -> shape, written from MODELS.md 2.2, 2.3 and 2.5 (independently of the model code)."""
    e = {"backbone.cls_token": (1, 1, d), "backbone.pos_embed": (1, 197, d),
         "backbone.pos_embed_z": (1, 64, d), "backbone.pos_embed_x": (1, 256, d),
         "backbone.patch_embed.proj.weight": (d, 3, 16, 16), "backbone.patch_embed.proj.bias": (d,),
         "backbone.norm.weight": (d,), "backbone.norm.bias": (d,)}
    for i in range(12):
        b = f"backbone.blocks.{i}."
        e.update({b + "norm1.weight": (d,), b + "norm1.bias": (d,),
                  b + "attn.qkv.weight": (3 * d, d), b + "attn.qkv.bias": (3 * d,),
                  b + "attn.proj.weight": (d, d), b + "attn.proj.bias": (d,),
                  b + "norm2.weight": (d,), b + "norm2.bias": (d,),
                  b + "mlp.fc1.weight": (4 * d, d), b + "mlp.fc1.bias": (4 * d,),
                  b + "mlp.fc2.weight": (d, 4 * d), b + "mlp.fc2.bias": (d,)})
    widths = [d, c, c // 2, c // 4, c // 8]
    for branch, out in (("ctr", 1), ("offset", 2), ("size", 2)):
        for i in range(4):
            k = f"box_head.conv{i + 1}_{branch}."
            cin, cout = widths[i], widths[i + 1]
            e.update({k + "0.weight": (cout, cin, 3, 3), k + "0.bias": (cout,),
                      k + "1.weight": (cout,), k + "1.bias": (cout,), k + "1.running_mean": (cout,),
                      k + "1.running_var": (cout,), k + "1.num_batches_tracked": ()})
        e.update({f"box_head.conv5_{branch}.weight": (out, c // 8, 1, 1), f"box_head.conv5_{branch}.bias": (out,)})
    return e


def test_state_dict_matches_official_layout():
    with torch.device("meta"):
        net = vit.OSTrackNet(vit.OSTRACK_256)
    got = {k: tuple(v.shape) for k, v in net.state_dict().items()}
    assert got == documented_layout()
    assert len(got) == 242
    assert sum(p.numel() for p in net.parameters()) == 92_518_533  # MODELS.md 2.5


def _tiny(seed: int = 0) -> "vit.OSTrackNet":
    torch.manual_seed(seed)
    net = vit.OSTrackNet(TINY)
    with torch.no_grad():  # non-trivial BatchNorm statistics, as a trained head has
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.1, 0.1)
                m.running_var.uniform_(0.5, 2.0)
                m.num_batches_tracked.fill_(1234)
    return net.eval()


def _inputs(seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(1, 3, 128, 128, generator=g), torch.randn(1, 3, 256, 256, generator=g)


def test_candidate_elimination_of_the_real_config():
    """vitb_256_mae_ce: keep ceil(0.7 L) search tokens at blocks 3, 6, 9, i.e. 256 -> 180 -> 126 ->
    89 (removed 76, 54, 37, MODELS.md 2.2); the query is the template centre token (3, 3) = 27;
    removed tokens come back as zero vectors in the 16 x 16 map."""
    net = _tiny()
    assert net.backbone.ce_query == 27
    assert net.backbone.keep_ratios == (1, 1, 1, 0.7, 1, 1, 0.7, 1, 1, 0.7, 1, 1)
    with torch.no_grad():
        feat, removed = net.backbone(*_inputs())
    assert [r.shape[1] for r in removed] == [76, 54, 37]
    gone = torch.cat(removed, dim=1)[0]
    assert len(set(gone.tolist())) == 167  # disjoint, 256 - 89
    zero = (feat[0].flatten(1).abs().sum(dim=0) == 0).nonzero().flatten()
    assert sorted(zero.tolist()) == sorted(gone.tolist())  # exactly the removed cells are zero
    with torch.no_grad():
        feat_off, removed_off = net.backbone(*_inputs(), keep_ratio=1.0)
    assert removed_off == [] and bool((feat_off[0].flatten(1).abs().sum(dim=0) > 0).all())


def test_eliminate_candidates_keeps_the_most_attended_tokens():
    """Hand-built attention: template query 1 of 2 attends to search token j with weight
    proportional to a known score (averaged over two heads); 5 search tokens, keep 0.5 -> 3."""
    nt, ns = 2, 5
    attn = torch.zeros(1, 2, nt + ns, nt + ns)
    attn[0, 0, 1, nt:] = torch.tensor([0.1, 0.5, 0.0, 0.3, 0.1])
    attn[0, 1, 1, nt:] = torch.tensor([0.1, 0.1, 0.2, 0.5, 0.1])  # mean: .1 .3 .1 .4 .1
    attn[0, :, 0, nt:] = torch.tensor([9.0, 0, 0, 0, 0])  # another query: ignored
    h = torch.arange(nt + ns, dtype=torch.float32).view(1, -1, 1).repeat(1, 1, 3)
    index = torch.tensor([[10, 11, 12, 13, 14]])  # global indices of the current search tokens
    new_h, kept, removed = vit.eliminate_candidates(h, attn, nt, 0.5, index, query=1)
    assert kept.tolist()[0][:2] == [13, 11]  # 0.4, 0.3 first, then one of the 0.1 ties
    assert set(kept.tolist()[0]) | set(removed.tolist()[0]) == {10, 11, 12, 13, 14}
    assert len(kept[0]) == 3 and len(removed[0]) == 2
    assert new_h[0, :nt, 0].tolist() == [0, 1]  # the template is untouched
    assert new_h[0, nt:, 0].tolist() == [float(k - 10 + nt) for k in kept[0].tolist()]
    same = vit.eliminate_candidates(h, attn, nt, 1.0, index, query=1)
    assert same[2] is None and torch.equal(same[0], h)


def test_hann_window_reference_values():
    w = hann_window_2d(16)
    assert w.max() == pytest.approx(0.983, abs=5e-4)  # MODELS.md 2.4
    assert w[0, 0] == pytest.approx(0.00114, abs=5e-6)
    assert np.unravel_index(np.argmax(w), w.shape) in {(7, 7), (7, 8), (8, 7), (8, 8)}
    np.testing.assert_allclose(w, w.T)
    np.testing.assert_allclose(w, w[::-1, ::-1])
    assert w[0, 0] > 0  # 'centered': no zero at the border


def test_center_head_box_hand_computed():
    f = 16
    resp = np.zeros((f, f))
    resp[5, 9] = 0.8  # row (y) 5, column (x) 9
    resp[12, 2] = 0.7
    size = np.zeros((2, f, f))
    size[:, 5, 9] = (0.25, 0.125)
    offset = np.zeros((2, f, f))
    offset[:, 5, 9] = (0.3, 0.6)
    np.testing.assert_allclose(center_head_box(resp, size, offset), [9.3 / 16, 5.6 / 16, 0.25, 0.125])


def test_checkpoint_round_trip_with_batchnorm_buffers(tmp_path):
    a, b = _tiny(0), _tiny(1)
    path = tmp_path / "OSTrack_ep0300.pth.tar"
    torch.save({"net": a.state_dict(), "epoch": 300, "net_type": "OSTrack"}, path)
    z, x = _inputs(3)
    with torch.no_grad():
        before = b(z, x)[0]
        vit.load_checkpoint(b, path, vit.OfficialCheckpoint("tiny", "OSTrack_ep0300.pth.tar", "src"))
        after, ref = b(z, x), a(z, x)
    assert not torch.equal(before, ref[0])
    for u, v in zip(after, ref):
        assert torch.equal(u, v)
    assert int(b.box_head.conv1_ctr[1].num_batches_tracked) == 1234


def test_head_outputs_are_clamped_sigmoids():
    with torch.no_grad():
        score, size, offset = _tiny()(*_inputs())
    assert score.shape == (1, 1, 16, 16) and size.shape == (1, 2, 16, 16) and offset.shape == (1, 2, 16, 16)
    for m in (score, size):
        assert float(m.min()) >= 1e-4 - 1e-9 and float(m.max()) <= 1 - 1e-4 + 1e-9


def test_tracker_outputs_and_prior():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (480, 480, 3), dtype=np.uint8)
    box = Box(100, 100, 12, 12)  # search crop ceil(12 * 4) = 48 px
    net = _tiny(2)
    trk = OSTrack(OSTrack.Params(), network=net)
    trk.initialize(img, box)
    out = trk.track(img)
    assert out.score_map.shape == (16, 16)
    assert out.confidence == pytest.approx(float(out.score_map.max()))  # raw sigmoid peak
    assert out.extra["peak_score"] == out.confidence and out.extra["hann_peak"] <= out.confidence
    assert math.dist(out.box.center, box.center) <= 48 / 2 * math.sqrt(2) + 1
    assert [out.extra[f"search_{c}"] for c in "xywh"] == [82, 82, 48, 48]   # the crop: 106 - 48 / 2
    trk = OSTrack(OSTrack.Params(), network=net)
    trk.initialize(img, box)
    out = trk.track(img, prior=(350.0, 300.0))
    assert math.dist(out.box.center, (350.0, 300.0)) <= 48 / 2 * math.sqrt(2) + 1
    assert [out.extra[f"search_{c}"] for c in "xywh"] == [326, 276, 48, 48]  # centred on the prior


def test_tracker_box_follows_the_hann_weighted_peak():
    """With the network replaced by fixed maps, the tracker's box is the centre-head box of the
    Hann-weighted map, mapped back to the image by hand."""
    f = 16

    class FixedMaps(torch.nn.Module):
        cfg = vit.OSTrackConfig(template_size=32, search_size=256)

        def forward(self, z, x, keep_ratio=None):
            score = torch.full((1, 1, f, f), 0.1)
            score[0, 0, 0, 0] = 0.9   # strong but at the corner: the Hann window suppresses it
            score[0, 0, 6, 10] = 0.6
            size = torch.full((1, 2, f, f), 0.25)
            offset = torch.full((1, 2, f, f), 0.5)
            return score, size, offset

    img = np.zeros((600, 600, 3), np.uint8)
    box = Box(280, 270, 40, 40)  # crop side 160 px, resize factor 256 / 160
    trk = OSTrack(OSTrack.Params(), network=FixedMaps())
    trk.initialize(img, box)
    out = trk.track(img)
    crop = 160.0
    cx = (10 + 0.5) / 16 * crop + box.cx - crop / 2
    cy = (6 + 0.5) / 16 * crop + box.cy - crop / 2
    np.testing.assert_allclose(out.box.as_array(), [cx - 20, cy - 20, 40, 40], atol=1e-9)
    assert out.confidence == pytest.approx(0.9)  # confidence: the raw peak, before the window
    raw = OSTrack(OSTrack.Params(hann_window=False), network=FixedMaps())
    raw.initialize(img, box)
    assert raw.track(img).box.center == pytest.approx((0.5 / 16 * crop + box.cx - crop / 2,
                                                       0.5 / 16 * crop + box.cy - crop / 2))


def test_missing_checkpoint_and_bad_params(monkeypatch):
    monkeypatch.delenv("MATA_OSTRACK", raising=False)
    with pytest.raises(FileNotFoundError, match=r"OSTrack_ep0300\.pth\.tar.*botaoye/OSTrack"):
        OSTrack()
    with pytest.raises(ValueError, match="ce_keep_ratio"):
        OSTrack(OSTrack.Params(ce_keep_ratio=0.0), network=_tiny())
