"""NanoTrack v2 (HonglinChu/SiamTrackers, ``configv2.yaml``) as a PyTorch module whose
``state_dict`` loads the published ``nanotrackv2.pth`` with strict key/shape matching, so the
ONNX pair the ``nanotrack`` tracker runs can be exported from the checkpoint
(``mata-eval export nanotrack``).

Architecture (written from the upstream description, not copied):

- backbone: the first nine layers of a MobileNetV3-small (``used_layers: [4]``): a 3x3/2 conv +
  BN + hard-swish stem and eight inverted-residual blocks (kernel, expansion, out, SE, h-swish,
  stride) = (3, 1, 16, SE, ReLU, 2), (3, 4.5, 24, -, ReLU, 2), (3, 3.67, 24, -, ReLU, 1),
  (5, 4, 40, SE, HS, 2), (5, 6, 40, SE, HS, 1) x2, (5, 3, 48, SE, HS, 1) x2; stride 16, 48
  channels (127 px -> 8x8, 255 px -> 16x16). The ``neck`` (1x1 conv 64 -> 64 + BN) is in the
  checkpoint but unused at inference (its ``AdjustLayer`` skips it when in == out channels and
  the model builder never calls it); it is kept so the state_dict matches.
- head (``DepthwiseBAN`` v2): two pixel-wise correlations (cls, reg): 1x1 conv + BN on template
  and search features, correlation as a matrix product template positions x search positions
  (8 x 8 = 64 output channels), channel attention (global average pool, 1x1 conv, ReLU, 1x1 conv,
  sigmoid, rescale); then per branch five depthwise-separable 3x3 layers (dw conv, pw conv, BN,
  ReLU6) and a 1x1 prediction conv; ``loc = exp(bbox_pred)``.

Inputs are raw 0..255 RGB float crops (NCHW), as ``cv2.TrackerNano`` feeds the ONNX pair.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
import torch.nn as nn

# (kernel, expansion, out channels, squeeze-excite, hard-swish, stride): MobileNetV3-small, the
# subset NanoTrack v2 keeps.
MOBILENETV3_SMALL_V2 = (
    (3, 1.0, 16, True, False, 2),
    (3, 4.5, 24, False, False, 2),
    (3, 3.67, 24, False, False, 1),
    (5, 4.0, 40, True, True, 2),
    (5, 6.0, 40, True, True, 1),
    (5, 6.0, 40, True, True, 1),
    (5, 3.0, 48, True, True, 1),
    (5, 3.0, 48, True, True, 1),
)
FEATURE_CHANNELS = 48
TEMPLATE_CELLS = 8   # 127 px exemplar / stride 16
HEAD_CHANNELS = 96


def make_divisible(v: float, divisor: int = 8) -> int:
    """Round a channel count to a multiple of ``divisor`` (MobileNet rule: never drop > 10 %)."""
    new_v = max(divisor, int(v + divisor / 2) // divisor * divisor)
    return new_v + divisor if new_v < 0.9 * v else new_v


class SqueezeExcite(nn.Module):
    """Global average pool, FC (reduce 4x, to a multiple of 8), ReLU, FC, hard-sigmoid, rescale."""

    def __init__(self, channels: int):
        super().__init__()
        hidden = make_divisible(channels // 4)
        self.fc = nn.Sequential(nn.Linear(channels, hidden), nn.ReLU(), nn.Linear(hidden, channels),
                                nn.Hardsigmoid())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = self.fc(x.mean(dim=(2, 3)))
        return x * w[:, :, None, None]


def _act(hard_swish: bool) -> nn.Module:
    return nn.Hardswish() if hard_swish else nn.ReLU()


class InvertedResidual(nn.Module):
    """MobileNetV3 block; module indices inside ``conv`` follow the checkpoint's keys."""

    def __init__(self, inp: int, hidden: int, out: int, k: int, stride: int, se: bool, hs: bool):
        super().__init__()
        self.identity = stride == 1 and inp == out
        dw = nn.Conv2d(hidden, hidden, k, stride, (k - 1) // 2, groups=hidden, bias=False)
        squeeze = SqueezeExcite(hidden) if se else nn.Identity()
        if inp == hidden:   # no expansion: dw, BN, act, SE, pw-linear, BN
            layers = [dw, nn.BatchNorm2d(hidden), _act(hs), squeeze,
                      nn.Conv2d(hidden, out, 1, bias=False), nn.BatchNorm2d(out)]
        else:               # pw, BN, act, dw, BN, SE, act, pw-linear, BN
            layers = [nn.Conv2d(inp, hidden, 1, bias=False), nn.BatchNorm2d(hidden), _act(hs),
                      dw, nn.BatchNorm2d(hidden), squeeze, _act(hs),
                      nn.Conv2d(hidden, out, 1, bias=False), nn.BatchNorm2d(out)]
        self.conv = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv(x) if self.identity else self.conv(x)


class Backbone(nn.Module):
    """MobileNetV3-small subset, stride 16, 48 output channels."""

    def __init__(self, cfgs=MOBILENETV3_SMALL_V2):
        super().__init__()
        channels = make_divisible(16)
        layers: list[nn.Module] = [nn.Sequential(nn.Conv2d(3, channels, 3, 2, 1, bias=False),
                                                 nn.BatchNorm2d(channels), nn.Hardswish())]
        for k, t, c, se, hs, s in cfgs:
            out = make_divisible(c)
            layers.append(InvertedResidual(channels, make_divisible(channels * t), out, k, s, se, hs))
            channels = out
        self.features = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features(x)


class Neck(nn.Module):
    """``AdjustLayer(64, 64)``: its weights are in the checkpoint, but with equal in/out channels
    upstream skips it, so ``forward`` is the identity (kept for strict loading)."""

    def __init__(self, channels: int = 64):
        super().__init__()
        self.downsample = nn.Sequential(nn.Conv2d(channels, channels, 1, bias=False), nn.BatchNorm2d(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x


class ChannelAttention(nn.Module):
    """Global average pool, 1x1 conv, ReLU, 1x1 conv, sigmoid; rescales the input channels."""

    def __init__(self, channels: int):
        super().__init__()
        self.fc1 = nn.Conv2d(channels, channels, 1)
        self.fc2 = nn.Conv2d(channels, channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = self.fc2(torch.relu(self.fc1(x.mean(dim=(2, 3), keepdim=True))))
        return x * torch.sigmoid(w)


class PixelwiseCorrelation(nn.Module):
    """1x1 conv + BN on both features, then ``out[b, i, y, x] = <z[b, :, i], x[b, :, y, x]>``
    over the template positions ``i`` (a batched matrix product), then channel attention."""

    def __init__(self, channels: int = FEATURE_CHANNELS, template_positions: int = TEMPLATE_CELLS ** 2):
        super().__init__()
        self.conv_kernel = nn.Sequential(nn.Conv2d(channels, channels, 1), nn.BatchNorm2d(channels))
        self.conv_search = nn.Sequential(nn.Conv2d(channels, channels, 1), nn.BatchNorm2d(channels))
        self.CA_layer = ChannelAttention(template_positions)

    def forward(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        z = self.conv_kernel(z)
        x = self.conv_search(x)
        b, c, h, w = x.shape
        corr = torch.matmul(z.flatten(2).transpose(1, 2), x.flatten(2))   # (b, Lz, h w)
        return self.CA_layer(corr.reshape(b, -1, h, w))


def _separable_tower(cin: int, width: int, depth: int) -> nn.Sequential:
    """``depth`` x (3x3 depthwise conv, 1x1 conv, BN, ReLU6), no conv biases."""
    layers: list[nn.Module] = []
    for i in range(depth):
        c = cin if i == 0 else width
        layers += [nn.Conv2d(c, c, 3, 1, 1, groups=c, bias=False), nn.Conv2d(c, width, 1, bias=False),
                   nn.BatchNorm2d(width), nn.ReLU6()]
    return nn.Sequential(*layers)


class BANHead(nn.Module):
    """NanoTrack v2 ``DepthwiseBAN``: ``(zf, xf) -> (cls logits (B, 2, H, W), loc (B, 4, H, W))``
    with ``loc`` the exp of the regression (distances to the box sides in search-crop pixels)."""

    def __init__(self, template_positions: int = TEMPLATE_CELLS ** 2, width: int = HEAD_CHANNELS, depth: int = 6):
        super().__init__()
        self.corr_pw_reg = PixelwiseCorrelation(FEATURE_CHANNELS, template_positions)
        self.corr_pw_cls = PixelwiseCorrelation(FEATURE_CHANNELS, template_positions)
        self.cls_pw_tower = _separable_tower(template_positions, width, depth)
        self.bbox_pw_tower = _separable_tower(template_positions, width, depth)
        self.cls_pred = nn.Sequential(nn.Conv2d(width, 2, 1))
        self.bbox_pred = nn.Sequential(nn.Conv2d(width, 4, 1))

    def forward(self, zf: torch.Tensor, xf: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        cls = self.cls_pred(self.cls_pw_tower(self.corr_pw_cls(zf, xf)))
        loc = torch.exp(self.bbox_pred(self.bbox_pw_tower(self.corr_pw_reg(zf, xf))))
        return cls, loc


class NanoTrackV2(nn.Module):
    """The full network; ``backbone`` maps a crop to features, ``ban_head`` pairs them."""

    def __init__(self):
        super().__init__()
        self.backbone = Backbone()
        self.neck = Neck()
        self.ban_head = BANHead()

    def forward(self, z: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.ban_head(self.backbone(z), self.backbone(x))


def init_random(model: nn.Module, seed: int) -> nn.Module:
    """Seeded random weights with non-trivial BN statistics (pipeline tests without a checkpoint)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, nn.Conv2d):
                n = m.kernel_size[0] * m.kernel_size[1] * m.out_channels
                m.weight.copy_(torch.randn(m.weight.shape, generator=g) * math.sqrt(2.0 / n))
                if m.bias is not None:
                    m.bias.copy_(torch.randn(m.bias.shape, generator=g) * 0.01)
            elif isinstance(m, nn.BatchNorm2d):
                m.weight.copy_(1.0 + 0.1 * torch.randn(m.weight.shape, generator=g))
                m.bias.copy_(0.1 * torch.randn(m.bias.shape, generator=g))
                m.running_mean.copy_(0.1 * torch.randn(m.running_mean.shape, generator=g))
                m.running_var.copy_(1.0 + 0.1 * torch.rand(m.running_var.shape, generator=g))
            elif isinstance(m, nn.Linear):
                m.weight.copy_(torch.randn(m.weight.shape, generator=g) * 0.1)
                m.bias.zero_()
    return model


# --- checkpoint ---------------------------------------------------------------------------------

SOURCE = "https://github.com/HonglinChu/SiamTrackers (NanoTrack/models/pretrained/nanotrackv2.pth)"


def _numpy_safe_globals() -> list:
    """The numpy objects a legacy pysot checkpoint pickles besides tensors (the optimizer state's
    scalars and dtypes), allowed for ``weights_only`` loading. ``numpy.core`` was renamed
    ``numpy._core`` in numpy 2; the pickle names the old path."""
    import numpy as np

    try:
        scalar = np._core.multiarray.scalar
    except AttributeError:   # numpy < 2
        scalar = np.core.multiarray.scalar
    allowed: list = [(scalar, "numpy.core.multiarray.scalar"), scalar, np.dtype]
    dtypes = getattr(np, "dtypes", None)
    if dtypes is not None:
        allowed += [getattr(dtypes, n) for n in dir(dtypes) if n.endswith("DType")]
    return allowed


def checkpoint_file(path: str | Path) -> Path:
    """``path``, or ``path/nanotrackv2.pth`` when it is the folder holding it (as the ViT
    trackers take theirs)."""
    path = Path(path).expanduser()
    return path / "nanotrackv2.pth" if path.is_dir() and (path / "nanotrackv2.pth").is_file() else path


def read_checkpoint(path: str | Path, trust_pickle: bool = False) -> dict[str, torch.Tensor]:
    """The ``state_dict`` of ``nanotrackv2.pth`` (a pysot trainer dict ``{epoch, state_dict,
    optimizer}``, or a bare state_dict). Weights-only unpickling with the numpy scalar/dtype
    globals allowed; ``trust_pickle`` is the explicit opt-in to full unpickling."""
    path = checkpoint_file(path)
    if not path.is_file():
        raise FileNotFoundError(f"NanoTrack checkpoint not found: {path} (expected nanotrackv2.pth from {SOURCE})")
    import pickle

    try:
        if trust_pickle:
            obj = torch.load(path, map_location="cpu", weights_only=False)
        else:
            with torch.serialization.safe_globals(_numpy_safe_globals()):
                obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        if isinstance(exc, pickle.UnpicklingError) and "Unsupported global" in str(exc) and not trust_pickle:
            refused = next(line.strip() for line in str(exc).splitlines() if "Unsupported global" in line)
            raise ValueError(f"{path}: weights-only loading refused the file ({refused}); if you trust it, export "
                             "it with `mata-eval export nanotrack --checkpoint FILE --trust-pickle` and use the "
                             "ONNX pair (the nanotrack tracker's torch backend loads weights only)") from exc
        # (QA pass: an ONNX graph was told to retry with --trust-pickle, which it had)
        raise ValueError(f"{path}: not a PyTorch checkpoint ({first}); expected nanotrackv2.pth from {SOURCE} "
                         "(an ONNX pair is named as the nanotrack tracker's backbone: and head:)") from exc
    sd = obj.get("state_dict", obj) if isinstance(obj, dict) else None
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise ValueError(f"{path}: expected a dict with 'state_dict' (tensors) or a bare state_dict")
    if sd and all(k.startswith("module.") for k in sd):
        sd = {k[len("module."):]: v for k, v in sd.items()}
    return dict(sd)


def load_nanotrack_v2(path: str | Path, trust_pickle: bool = False) -> NanoTrackV2:
    """Build the network and load ``path`` strictly (a key or shape mismatch raises, naming it)."""
    model = NanoTrackV2()
    sd = read_checkpoint(path, trust_pickle)
    own = model.state_dict()
    missing = sorted(set(own) - set(sd))
    unexpected = sorted(set(sd) - set(own))
    shapes = [f"{k}: file {tuple(sd[k].shape)} vs model {tuple(own[k].shape)}"
              for k in own if k in sd and sd[k].shape != own[k].shape]
    if missing or unexpected or shapes:
        raise ValueError(f"{path} is not a NanoTrack v2 checkpoint: missing {missing[:5]}, "
                         f"unexpected {unexpected[:5]}, shape mismatches {shapes[:5]}")
    model.load_state_dict(sd, strict=True)
    return model.eval()


def torch_runners(checkpoint: str | Path, trust_pickle: bool = False, threads: int = 0, device: str = "cpu"):
    """The backbone and head as ``run(feeds) -> outputs`` callables with the published ONNX
    pair's names (``input`` -> ``output``; ``input1``, ``input2`` -> ``output1``, ``output2``), so
    the ``nanotrack`` tracker runs on torch with its ONNX pre/post-processing unchanged; the
    model runs on ``device`` (a torch device string)."""
    import numpy as np

    if threads > 0:
        torch.set_num_threads(threads)
    model = load_nanotrack_v2(checkpoint, trust_pickle).to(device)

    def tensor(a):
        return torch.from_numpy(np.ascontiguousarray(a)).to(device)

    def backbone(feeds):
        with torch.inference_mode():
            return {"output": model.backbone(tensor(feeds["input"])).cpu().numpy()}

    def head(feeds):
        with torch.inference_mode():
            cls, loc = model.ban_head(tensor(feeds["input1"]), tensor(feeds["input2"]))
        return {"output1": cls.cpu().numpy(), "output2": loc.cpu().numpy()}

    return backbone, head
