"""MixFormerV2 in PyTorch: the official state_dict layout (MODELS.md 1.7, every key and shape, the
published parameter counts), checkpoint loading (strict, safe by default), the template key/value
cache against the full forward, PMF window confidence on hand-built PMFs, score-gated template
update on hand-computed timelines, the MATA prior and the BGR -> RGB preprocessing."""

from __future__ import annotations

import math
import sys
import types

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from mata_eval.types import Box  # noqa: E402
from mata_eval_plugins.trackers import vit  # noqa: E402
from mata_eval_plugins.trackers.mixformerv2 import (  # noqa: E402
    CheckpointNotFound,
    MixFormerV2,
    TemplateSchedule,
)

TINY = vit.MixFormerV2Config(template_size=32, search_size=64, depth=2, mlp_ratio=2.0, embed_dim=32,
                             num_heads=2, feat_sz=16)


def documented_layout(ls: int, lt: int, depth: int, r: int, d: int = 768, n: int = 96) -> dict:
    """Key -> shape, written from MODELS.md 1.7 (independently of the model code)."""
    e = {"backbone.pos_embed_s": (1, ls, d), "backbone.pos_embed_t": (1, lt, d),
         "backbone.reg_tokens": (1, 4, d), "backbone.pos_embed_reg": (1, 4, d),
         "backbone.patch_embed.proj.weight": (d, 3, 16, 16), "backbone.patch_embed.proj.bias": (d,)}
    for i in range(depth):
        b = f"backbone.blocks.{i}."
        e.update({b + "norm1.weight": (d,), b + "norm1.bias": (d,),
                  b + "attn.qkv.weight": (3 * d, d), b + "attn.qkv.bias": (3 * d,),
                  b + "attn.proj.weight": (d, d), b + "attn.proj.bias": (d,),
                  b + "norm2.weight": (d,), b + "norm2.bias": (d,),
                  b + "mlp.fc1.weight": (d * r, d), b + "mlp.fc1.bias": (d * r,),
                  b + "mlp.fc2.weight": (d, d * r), b + "mlp.fc2.bias": (d,)})
    e.update({"box_head.layers.0.0.weight": (d, d), "box_head.layers.0.0.bias": (d,),
              "box_head.layers.0.1.weight": (d,), "box_head.layers.0.1.bias": (d,),
              "box_head.layers.1.0.weight": (n, d), "box_head.layers.1.0.bias": (n,),
              "box_head.layers.1.1.weight": (n,), "box_head.layers.1.1.bias": (n,),
              "score_head.layers.0.0.weight": (d, d), "score_head.layers.0.0.bias": (d,),
              "score_head.layers.1.weight": (1, d), "score_head.layers.1.bias": (1,)})
    return e


@pytest.mark.parametrize("cfg, ls, lt, depth, r, n_keys, n_params", [
    (vit.MIXFORMERV2_S, 196, 49, 4, 1, 66, 16_228_897),
    (vit.MIXFORMERV2_B, 324, 64, 8, 4, 114, 58_855_201),
])
def test_state_dict_matches_official_layout(cfg, ls, lt, depth, r, n_keys, n_params):
    with torch.device("meta"):  # shapes only, nothing computed
        net = vit.MixFormerV2Net(cfg)
    got = {k: tuple(v.shape) for k, v in net.state_dict().items()}
    assert got == documented_layout(ls, lt, depth, r)
    assert len(got) == n_keys
    assert sum(p.numel() for p in net.parameters()) == n_params  # MODELS.md 1.1, measured upstream


def _inputs(seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(1, 3, 32, 32, generator=g), torch.randn(1, 3, 32, 32, generator=g),
            torch.randn(1, 3, 64, 64, generator=g))


def _tiny(seed: int = 0) -> "vit.MixFormerV2Net":
    torch.manual_seed(seed)
    return vit.MixFormerV2Net(TINY).eval()


def test_forward_shapes_pmfs_and_box_is_the_expectation():
    net = _tiny()
    with torch.no_grad():
        box, logit, pmfs = net(*_inputs())
    assert box.shape == (1, 4) and logit.shape == (1,) and pmfs.shape == (1, 4, TINY.feat_sz)
    p = pmfs[0].double().numpy()
    assert np.all(p >= 0) and np.allclose(p.sum(axis=1), 1.0, atol=1e-6)
    # MODELS.md 1.3: side = sum_j p_j j / N (bins at j * stride, crop side N * stride)
    left, top, right, bottom = (p * np.arange(TINY.feat_sz)).sum(axis=1) / TINY.feat_sz
    expected = [(left + right) / 2, (top + bottom) / 2, right - left, bottom - top]
    np.testing.assert_allclose(box[0].double().numpy(), expected, atol=1e-6)


def test_template_cache_equals_full_forward():
    net = _tiny(3)
    z, oz, x = _inputs(1)
    with torch.no_grad():
        full = net(z, oz, x)
        cached = net.forward_search(x, net.encode_templates(z, oz))
        other = net(z, torch.zeros_like(oz), x)  # the online template matters
    for a, b in zip(full, cached):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-6)
    assert not torch.allclose(full[2], other[2])


def test_template_features_ignore_the_search_region():
    """Asymmetric attention: the template tokens' keys/values at every block do not depend on
    the search image, so the cache is exact (MODELS.md 1.2). Checked through the full forward:
    two searches that differ give the same outputs as their own cached passes."""
    net = _tiny(4)
    z, oz, x = _inputs(2)
    cache = net.encode_templates(z, oz)
    with torch.no_grad():
        for xs in (x, torch.flip(x, dims=[3]), x * 0.5):
            for a, b in zip(net(z, oz, xs), net.forward_search(xs, cache)):
                torch.testing.assert_close(a, b, rtol=0, atol=1e-6)


def _documented_small_checkpoint(seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {k: torch.randn(s, generator=g) * 0.02 for k, s in documented_layout(196, 49, 4, 1).items()}


def test_official_small_layout_loads_strictly_through_the_tracker(tmp_path):
    sd = _documented_small_checkpoint()
    path = tmp_path / "mixformerv2_small.pth.tar"
    torch.save({"epoch": 500, "net_type": "MixFormer", "net": sd, "optimizer": None}, path)
    trk = MixFormerV2(MixFormerV2.Params(variant="S", checkpoint=str(tmp_path)))  # a folder works
    net = trk.network()
    own = net.state_dict()
    assert set(own) == set(sd)
    for k in sd:
        assert torch.equal(own[k], sd[k]), k
    img = np.full((240, 320, 3), 90, np.uint8)
    trk.initialize(img, Box(140, 100, 30, 24))
    out = trk.track(img)
    assert out.pmfs.shape == (4, 96) and np.isfinite(out.box.as_array()).all()


def test_checkpoint_round_trip_tiny(tmp_path):
    a, b = _tiny(0), _tiny(1)
    path = tmp_path / "tiny.pth.tar"
    torch.save({"net": a.state_dict(), "epoch": 1, "constructor": None}, path)
    x = _inputs(5)
    with torch.no_grad():
        assert not torch.allclose(a(*x)[2], b(*x)[2])
        vit.load_checkpoint(b, path, vit.OfficialCheckpoint("tiny", "tiny.pth.tar", "here"))
        for u, v in zip(a(*x), b(*x)):
            assert torch.equal(u, v)
    bare = tmp_path / "bare.pth"
    torch.save(a.state_dict(), bare)  # a bare state_dict is accepted too
    c = _tiny(2)
    vit.load_checkpoint(c, bare, vit.OfficialCheckpoint("tiny", "tiny.pth.tar", "here"))
    assert all(torch.equal(c.state_dict()[k], v) for k, v in a.state_dict().items())


def test_wrong_variant_is_named(tmp_path):
    path = tmp_path / "mixformerv2_small.pth.tar"
    torch.save({"net": _documented_small_checkpoint()}, path)
    trk = MixFormerV2(MixFormerV2.Params(variant="B", checkpoint=str(path)))
    with pytest.raises(vit.CheckpointError) as e:
        trk.network()
    msg = str(e.value)
    assert "mixformerv2_base.pth.tar" in msg and "MixFormerV2-B" in msg
    assert "backbone.pos_embed_s: file (1, 196, 768) vs model (1, 324, 768)" in msg
    assert "missing key(s)" in msg  # blocks 4..7
    assert msg.endswith("It is a MixFormerV2-S checkpoint: set variant: S")   # the fix, named
    with pytest.raises(vit.CheckpointError, match="set variant: S$"):   # by the preflight too
        trk.check()


def test_missing_checkpoint_names_file_and_source(tmp_path, monkeypatch):
    monkeypatch.delenv("MATA_MIXFORMERV2_S", raising=False)
    with pytest.raises(CheckpointNotFound, match=r"mixformerv2_small\.pth\.tar.*MCG-NJU/MixFormerV2"):
        MixFormerV2(MixFormerV2.Params(variant="S"))
    monkeypatch.setenv("MATA_MIXFORMERV2_B", str(tmp_path / "nowhere.pth.tar"))
    with pytest.raises(CheckpointNotFound, match=r"nowhere\.pth\.tar.*\$MATA_MIXFORMERV2_B.*mixformerv2_base"):
        MixFormerV2(MixFormerV2.Params(variant="B"))


def test_legacy_pickle_needs_explicit_trust(tmp_path):
    """A trainer checkpoint that pickles its settings object (a class of the upstream trainer,
    not importable here) is refused by default and loads with trust_pickle."""
    mod = types.ModuleType("lib_train_admin_fake")

    class Settings:
        def __init__(self):
            self.env = {"workspace": "/x"}

    Settings.__module__ = mod.__name__
    Settings.__qualname__ = "Settings"
    mod.Settings = Settings
    sys.modules[mod.__name__] = mod
    try:
        a = _tiny(0)
        path = tmp_path / "legacy.pth.tar"
        torch.save({"net": a.state_dict(), "settings": Settings()}, path)
    finally:
        del sys.modules[mod.__name__]
    official = vit.OfficialCheckpoint("tiny", "tiny.pth.tar", "https://example.org/weights")
    b = _tiny(1)
    with pytest.raises(vit.CheckpointError, match=r"legacy\.pth\.tar.*trust_pickle: true"):
        vit.load_checkpoint(b, path, official)
    vit.load_checkpoint(b, path, official, trust_pickle=True)
    assert all(torch.equal(b.state_dict()[k], v) for k, v in a.state_dict().items())


def test_not_a_checkpoint(tmp_path):
    path = tmp_path / "junk.pth.tar"
    path.write_bytes(b"not a torch file")
    with pytest.raises(vit.CheckpointError, match=r"junk\.pth\.tar.*not a readable torch checkpoint.*small"):
        vit.load_checkpoint(_tiny(), path, vit.OfficialCheckpoint("S", "mixformerv2_small.pth.tar", "src"))
    torch.save({"net": [1, 2, 3]}, path)
    with pytest.raises(vit.CheckpointError, match="expected a trainer checkpoint"):
        vit.load_checkpoint(_tiny(), path, vit.OfficialCheckpoint("S", "mixformerv2_small.pth.tar", "src"))


# ------------------------------------------------------------------------------------------
# confidence and template update, through the tracker with a scripted network


N = 16


class ScriptedNet(torch.nn.Module):
    """Returns hand-built PMFs / score logits and records each installed online template."""

    def __init__(self, outputs):
        super().__init__()
        self.cfg = vit.MixFormerV2Config(template_size=32, search_size=64, depth=1, embed_dim=8,
                                         num_heads=1, feat_sz=N)
        self.outputs = list(outputs)
        self.installed: list[float] = []

    def encode_templates(self, z, oz):
        self.installed.append(float(oz[0, 0, 0, 0]))
        return []

    def forward_search(self, x, cache):
        pmfs, logit = self.outputs.pop(0)
        box = torch.tensor([[0.5, 0.5, 0.2, 0.2]])
        return box, torch.tensor([float(logit)]), torch.tensor(np.asarray(pmfs), dtype=torch.float64)[None]


def _delta(k: int) -> np.ndarray:
    p = np.zeros(N)
    p[k] = 1.0
    return p


def _run(outputs, images=None, **params):
    net = ScriptedNet(outputs)
    trk = MixFormerV2(MixFormerV2.Params(**params), network=net)
    images = images or [np.full((200, 200, 3), 40, np.uint8)] * (len(outputs) + 1)
    trk.initialize(images[0], Box(90, 90, 20, 20))
    return net, [trk.track(im) for im in images[1:]]


def test_window_confidence_on_hand_built_pmfs():
    uniform = np.full(N, 1.0 / N)
    two_modes = np.zeros(N)
    two_modes[[3, 11]] = 0.5
    edge = np.zeros(N)
    edge[:3] = (0.5, 0.3, 0.2)
    edge_right = edge[::-1].copy()
    wide = np.zeros(N)
    wide[6:11] = 0.2  # mode at bin 6 (first of the ties), window 5..7 holds 0.4
    cases = [
        ([_delta(8)] * 4, 1.0),                                   # delta
        ([uniform] * 4, 2.0 / N),                                 # uniform: argmax 0, truncated window
        ([two_modes, _delta(2), _delta(5), _delta(9)], 0.5),      # two equal modes -> 1/2, min over sides
        ([_delta(1), edge, _delta(4), _delta(7)], 0.8),           # peak at the left edge, truncated
        ([_delta(1), _delta(2), edge_right, _delta(7)], 0.8),     # peak at the right edge
        ([_delta(1), _delta(2), _delta(3), wide], 0.4),
    ]
    # N = 16 bins: alpha = 0.125 gives 2 round(0.125 * 16 / 2) + 1 = 3 bins, the width the
    # paper's alpha = 0.03 gives for N = 96 (checked in the next test)
    _, outs = _run([(pmfs, 0.0) for pmfs, _ in cases], window_alpha=0.125, template_update="none")
    for out, (pmfs, expected) in zip(outs, cases):
        assert out.confidence == pytest.approx(expected, abs=1e-9)
        assert out.extra["window_score"] == pytest.approx(expected, abs=1e-9)
        assert out.extra["mlp_score"] == pytest.approx(0.5)
        np.testing.assert_allclose(out.pmfs, np.asarray(pmfs), atol=1e-12)


def test_pmf_spread_in_image_pixels():
    """Two modes of 1/2 at bins 3 and 11: sd = 4 bins. Crop side ceil(sqrt(20 * 20) * 4.5) = 90 px
    over 16 bins -> 5.625 px per bin -> 22.5 px; a delta has no spread."""
    two_modes = np.zeros(N)
    two_modes[[3, 11]] = 0.5
    _, outs = _run([([two_modes, _delta(2), _delta(5), _delta(9)], 0.0)], template_update="none")
    extra = outs[0].extra
    assert extra["sigma_left"] == pytest.approx(22.5)
    assert extra["sigma_top"] == extra["sigma_right"] == extra["sigma_bottom"] == pytest.approx(0.0, abs=1e-6)


def test_paper_alpha_window_is_three_bins_of_96():
    global N
    p = np.zeros(96)
    p[[40, 41, 42, 43]] = (0.1, 0.5, 0.3, 0.1)  # mode 41, bins 40..42 -> 0.9
    old, N = N, 96
    try:
        _, outs = _run([([p, _delta(3), _delta(5), _delta(9)], 0.0)], template_update="none")
    finally:
        N = old
    assert outs[0].confidence == pytest.approx(0.9)


def test_mlp_confidence_is_the_sigmoid_score():
    _, outs = _run([([_delta(3)] * 4, math.log(3.0))], confidence="mlp", template_update="none")
    assert outs[0].confidence == pytest.approx(0.75)
    assert outs[0].extra["window_score"] == pytest.approx(1.0)


def _pixel(v: int) -> float:
    """Normalised R channel of a grey level, as the template tensor holds it."""
    return (v / 255.0 - 0.485) / 0.229


def test_threshold_update_timeline():
    scores = [0.4, 0.6, 0.5, 0.9]  # tau 0.5: updates at frames 2 and 4 (strictly above)
    images = [np.full((200, 200, 3), 10 * (k + 1), np.uint8) for k in range(5)]
    net, outs = _run([([_delta(2)] * 4, math.log(s / (1 - s))) for s in scores], images=images,
                     confidence="mlp", tau_template=0.5, template_update="threshold")
    assert [o.extra["template_updated"] for o in outs] == [0.0, 1.0, 0.0, 1.0]
    # installed: initial template (frame 0), then the crops of frames 2 and 4
    assert net.installed == pytest.approx([_pixel(10), _pixel(30), _pixel(50)], abs=1e-5)


def test_interval_update_timeline():
    """Upstream policy: keep the best crop above tau within each interval, install it every
    `update_interval` frames, fall back to the initial template when none qualified."""
    scores = [0.6, 0.8, 0.7, 0.4, 0.3, 0.2, 0.9]
    images = [np.full((200, 200, 3), 10 * (k + 1), np.uint8) for k in range(len(scores) + 1)]
    net, outs = _run([([_delta(2)] * 4, math.log(s / (1 - s))) for s in scores], images=images,
                     confidence="mlp", tau_template=0.5, template_update="interval", update_interval=3)
    assert [o.extra["template_updated"] for o in outs] == [0, 0, 1, 0, 0, 1, 0]
    # frame 3 installs frame 2's crop (best 0.8); frame 6 has no candidate -> initial template
    assert net.installed == pytest.approx([_pixel(10), _pixel(30), _pixel(10)], abs=1e-5)


def test_schedule_none_and_validation():
    s = TemplateSchedule("none", 0.0)
    assert [s.step(1.0) for _ in range(3)] == [(False, False)] * 3
    with pytest.raises(ValueError, match="update_interval"):
        TemplateSchedule("interval", 0.5, 0)
    with pytest.raises(ValueError, match="template_update"):
        TemplateSchedule("sometimes", 0.5)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------
# the tracker with a tiny random network: prior, RGB, shapes


def _tracker(**params) -> MixFormerV2:
    return MixFormerV2(MixFormerV2.Params(**params), network=_tiny(7))


def test_track_outputs_and_prior_centres_the_search_region():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (400, 400, 3), dtype=np.uint8)
    box = Box(100, 100, 10, 10)  # crop side ceil(10 * 4.5) = 45 px
    trk = _tracker()
    trk.initialize(img, box)
    out = trk.track(img)
    assert out.pmfs.shape == (4, TINY.feat_sz)
    np.testing.assert_allclose(out.pmfs.sum(axis=1), 1.0, atol=1e-6)
    assert 0.0 < out.confidence <= 1.0 and 0.0 < out.extra["mlp_score"] < 1.0
    assert math.dist(out.box.center, box.center) <= 45 / 2 + 1
    # the search region it cropped (frames.csv's search_*): corner round(105 - 22.5) = 82 (half to even)
    assert [out.extra[f"search_{c}"] for c in "xywh"] == [82, 82, 45, 45]
    trk = _tracker()
    trk.initialize(img, box)
    out = trk.track(img, prior=(300.0, 250.0))  # the MATA feedback moves the search region
    assert math.dist(out.box.center, (300.0, 250.0)) <= 45 / 2 + 1
    assert [out.extra[f"search_{c}"] for c in "xywh"] == [278, 228, 45, 45]   # round(277.5), round(227.5)


def test_cached_and_full_trackers_agree():
    rng = np.random.default_rng(1)
    frames = [rng.integers(0, 255, (160, 160, 3), dtype=np.uint8) for _ in range(4)]
    outs = []
    for cache in (True, False):
        trk = _tracker(template_cache=cache, tau_template=0.0)  # update on every frame
        trk.initialize(frames[0], Box(60, 60, 20, 20))
        outs.append([trk.track(f) for f in frames[1:]])
    for a, b in zip(*outs):
        np.testing.assert_allclose(a.box.as_array(), b.box.as_array(), atol=1e-3)
        np.testing.assert_allclose(a.pmfs, b.pmfs, atol=1e-5)
        assert a.extra["template_updated"] == b.extra["template_updated"] == 1.0


def test_preprocessing_is_rgb_imagenet():
    blue = np.zeros((4, 4, 3), np.uint8)
    blue[..., 0] = 255  # BGR: pure blue
    x = vit.image_to_tensor(blue)
    assert x.shape == (1, 3, 4, 4)
    np.testing.assert_allclose(x[0, :, 0, 0].numpy(), [(0 - 0.485) / 0.229, (0 - 0.456) / 0.224,
                                                       (1 - 0.406) / 0.225], rtol=1e-6)


def test_bad_input():
    trk = _tracker()
    with pytest.raises(RuntimeError, match="before initialize"):
        trk.track(np.zeros((50, 50, 3), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        trk.initialize(np.zeros((50, 50), np.uint8), Box(1, 1, 5, 5))
    with pytest.raises(ValueError, match="positive size"):
        trk.initialize(np.zeros((50, 50, 3), np.uint8), Box(1, 1, 0, 5))
    with pytest.raises(ValueError, match="variant"):
        MixFormerV2(MixFormerV2.Params(variant="L"), network=_tiny())  # type: ignore[arg-type]


def test_sincos_position_embedding():
    pe = vit.sincos_pos_embed_2d(8, 3)  # 9 tokens, channels: [sin(x w), cos(x w), sin(y w), cos(y w)]
    w = np.array([1.0, 0.01])
    for r in range(3):
        for c in range(3):
            expected = np.r_[np.sin(c * w), np.cos(c * w), np.sin(r * w), np.cos(r * w)]
            np.testing.assert_allclose(pe[r * 3 + c], expected, atol=1e-7)


def test_random_weights_are_seeded_and_leave_the_global_rng_alone():
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    a = MixFormerV2(MixFormerV2.Params(random_weights=True, seed=5)).network()
    assert torch.equal(torch.rand(3), expected)
    b = MixFormerV2(MixFormerV2.Params(random_weights=True, seed=5)).network()
    c = MixFormerV2(MixFormerV2.Params(random_weights=True, seed=6)).network()
    assert torch.equal(a.backbone.reg_tokens, b.backbone.reg_tokens)
    assert not torch.equal(a.backbone.reg_tokens, c.backbone.reg_tokens)


def _folder_dataset(root, n: int = 3):
    """One sequence ``s`` of ``n`` textured 240 x 320 frames with a bright square."""
    import cv2

    seq = root / "s"
    (seq / "img").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for k in range(n):
        img = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
        img[100:124, 140 + 2 * k:170 + 2 * k] = 250
        cv2.imwrite(str(seq / "img" / f"{k:04d}.jpg"), img)
    np.savetxt(seq / "groundtruth_rect.txt", [[140 + 2 * k, 100, 30, 24] for k in range(n)], delimiter=",")


def test_a_run_records_its_checkpoint_and_refuses_results_of_another(tmp_path, monkeypatch):
    """The checkpoint found through $MATA_MIXFORMERV2_S is in no YAML value: the manifest records
    its path and sha256, and a rerun with another checkpoint does not resume the old results
    (QA pass: a rerun with other weights kept the finished sequences)."""
    import hashlib
    import json

    from mata_eval.run.config import load_experiment
    from mata_eval.run.runner import ResultsConflict, run_experiment

    _folder_dataset(tmp_path / "data")
    a, b = tmp_path / "a" / "mixformerv2_small.pth.tar", tmp_path / "b" / "mixformerv2_small.pth.tar"
    for seed, path in ((0, a), (1, b)):
        path.parent.mkdir()
        torch.save({"net": _documented_small_checkpoint(seed)}, path)
    exp_file = tmp_path / "exp.yaml"
    exp_file.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: folder, root: {tmp_path / 'data'}}}\n"
                        "tracker: {name: mixformerv2, threads: 1}\n")
    monkeypatch.setenv("MATA_MIXFORMERV2_S", str(a.parent))
    quiet = dict(jobs=1, progress=False, log=lambda s: None)
    assert [o.status for o in run_experiment(load_experiment(exp_file), **quiet)] == ["done"]
    manifest = json.loads((tmp_path / "out" / "exp" / "manifest.json").read_text())
    assert manifest["model_files"] == {"checkpoint": {"path": str(a), "sha256": hashlib.sha256(a.read_bytes()).hexdigest()}}
    assert [o.status for o in run_experiment(load_experiment(exp_file), **quiet)] == ["skipped"]
    monkeypatch.setenv("MATA_MIXFORMERV2_S", str(b.parent))
    with pytest.raises(ResultsConflict, match=r"another checkpoint file .*a/mixformerv2_small.* than .*b/mixformerv2_small"):
        run_experiment(load_experiment(exp_file), **quiet)


def test_a_run_of_random_weights_says_so_in_its_manifest(tmp_path, capsys):
    """QA pass 16c: the random-weights warning was printed, not kept with the run."""
    import json

    from mata_eval.run.config import load_experiment
    from mata_eval.run.runner import run_experiment

    _folder_dataset(tmp_path / "data", n=2)
    exp_file = tmp_path / "exp.yaml"
    exp_file.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: folder, root: {tmp_path / 'data'}}}\n"
                        "tracker: {name: mixformerv2, threads: 1, random_weights: true}\n")
    run_experiment(load_experiment(exp_file), jobs=1, progress=False, log=lambda s: None)
    warnings = json.loads((tmp_path / "out" / "exp" / "manifest.json").read_text())["warnings"]
    line = "tracker mixformerv2 (run exp): random_weights: true, so its scores measure timing and plumbing, not tracking"
    assert warnings == [line]
    from mata_eval import cli   # and a later report says it again (QA pass 16d: nothing read it back)

    assert cli.main(["report", str(tmp_path / "out" / "exp")]) == 0
    assert f"warning recorded when exp ran: {line}" in capsys.readouterr().out


def test_model_files_of_each_configuration(tmp_path, monkeypatch):
    from mata_eval_plugins.trackers.ostrack import OSTrack

    monkeypatch.setenv("MATA_OSTRACK", str(tmp_path))
    (tmp_path / "OSTrack_ep0300.pth.tar").write_bytes(b"x")
    assert OSTrack.model_files(OSTrack.Params()) == {"checkpoint": tmp_path / "OSTrack_ep0300.pth.tar"}
    assert OSTrack.model_files(OSTrack.Params(random_weights=True)) == {}
    assert MixFormerV2.model_files(MixFormerV2.Params(random_weights=True)) == {}
    path = tmp_path / "mine.pth.tar"
    path.write_bytes(b"x")
    assert MixFormerV2.model_files(MixFormerV2.Params(variant="B", checkpoint=str(path))) == {"checkpoint": path}


def test_the_preflight_names_a_checkpoints_missing_keys(tmp_path):
    """QA pass: a checkpoint without two tensors passed `validate` and failed every sequence."""
    from mata_eval.run.config import load_experiment
    from mata_eval.run.preflight import plan

    _folder_dataset(tmp_path / "data", n=2)
    sd = _documented_small_checkpoint()
    del sd["backbone.reg_tokens"], sd["score_head.layers.1.weight"]
    torch.save({"net": sd}, tmp_path / "missing.pth.tar")
    exp_file = tmp_path / "exp.yaml"
    exp_file.write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: folder, root: {tmp_path / 'data'}}}\n"
                        f"tracker: {{name: mixformerv2, checkpoint: {tmp_path / 'missing.pth.tar'}}}\n")
    problems = plan(load_experiment(exp_file)).problems
    assert len(problems) == 1 and "tracker mixformerv2" in problems[0]
    assert "missing.pth.tar does not match MixFormerV2-S" in problems[0]
    assert "2 missing key(s): backbone.reg_tokens, score_head.layers.1.weight" in problems[0]
    torch.save({"net": _documented_small_checkpoint()}, tmp_path / "missing.pth.tar")   # the whole one passes
    assert plan(load_experiment(exp_file)).problems == ()


@pytest.mark.parametrize("tracker, key, value, expected", [
    ("mixformerv2", "window_alpha", 1.5, "window_alpha: expected a number in [0, 1]"),
    ("mixformerv2", "window_alpha", ".nan", "window_alpha: expected a number in [0, 1]"),
    ("mixformerv2", "search_factor", 0, "search_factor: expected a positive finite number"),
    ("mixformerv2", "template_factor", ".inf", "template_factor: expected a positive finite number"),
    ("ostrack", "search_factor", ".inf", "search_factor: expected a positive finite number"),
    # QA pass 13: a bare "'cuda:1'" (a KeyError) at the first frame; a checkpoint silently ignored
    ("ostrack", "backend: onnxruntime\n  onnx: x\n  device", "cuda:1", "device: expected one of cpu, cuda, tensorrt"),
    ("mixformerv2", "random_weights: true\n  checkpoint", "ck.pth.tar", "random_weights: true ignores checkpoint"),
    ("ostrack", "threads", -1, "threads: expected 0 (leave the library's setting) or more"),
    ("mixformerv2", "update_interval", 0, "update_interval: expected >= 1"),
    ("ostrack", "ce_keep_ratio", 1.5, "ce_keep_ratio: expected a number in (0, 1]"),
    ("vittrack", "window_alpha", -0.1, "window_alpha: expected a number in [0, 1]"),
    ("nanotrack", "window_alpha", 1.5, "window_alpha: expected a number in [0, 1]"),
])
def test_out_of_range_parameters_are_refused_when_the_experiment_is_loaded(tmp_path, tracker, key, value, expected):
    """QA pass: window_alpha 1.5 passed `validate` and failed each sequence at its first frame."""
    from mata_eval.core.params import ConfigError
    from mata_eval.run.config import load_experiment

    exp_file = tmp_path / "exp.yaml"
    exp_file.write_text(f"output: out\ndataset: {{name: folder, root: data}}\n"
                        f"tracker:\n  name: {tracker}\n  {key}: {value}\n")
    with pytest.raises(ConfigError) as e:
        load_experiment(exp_file)
    assert "exp.yaml:3" in str(e.value) and expected in str(e.value)
