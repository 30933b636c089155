"""Torch networks of the two one-stream ViT trackers, MixFormerV2 and OSTrack, their shared ViT
blocks, the ImageNet preprocessing and the safe checkpoint loader (MODELS.md sections 1 and 2).

This module imports torch: the tracker plugins import it only when a tracker is built, so that
``mata-eval list`` works without torch (an optional extra).

Parameter names and shapes follow the official checkpoints (``mixformerv2_small.pth.tar``,
``mixformerv2_base.pth.tar``, ``OSTrack_ep0300.pth.tar``) so they load with strict matching:
MixFormerV2 ``backbone.{pos_embed_s, pos_embed_t, reg_tokens, pos_embed_reg, patch_embed.proj,
blocks.i.*}``, ``box_head.layers.*``, ``score_head.layers.*`` (MODELS.md 1.7); OSTrack
``backbone.{cls_token, pos_embed, pos_embed_z, pos_embed_x, patch_embed.proj, blocks.i.*, norm}``
and ``box_head.conv{1..5}_{ctr,offset,size}`` (MODELS.md 2.5). The code is written from the
architecture description, not copied from upstream.
"""

from __future__ import annotations

import math
import pickle
import re
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


# --------------------------------------------------------------------------------------------
# preprocessing


def image_to_tensor(patch_bgr: np.ndarray, device: str | torch.device = "cpu") -> torch.Tensor:
    """BGR uint8 HWC crop -> RGB, ``/255``, ImageNet mean/std, NCHW float32 batch of one
    (upstream ``Preprocessor``; the networks were trained on RGB, MODELS.md 1.8 pitfall 4)."""
    if patch_bgr.ndim != 3 or patch_bgr.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) BGR crop, got shape {patch_bgr.shape}")
    rgb = np.ascontiguousarray(patch_bgr[:, :, ::-1])
    x = torch.from_numpy(rgb).to(device=device, dtype=torch.float32).permute(2, 0, 1).unsqueeze(0)
    mean = torch.tensor(IMAGENET_MEAN, device=x.device).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD, device=x.device).view(1, 3, 1, 1)
    return (x / 255.0 - mean) / std


# --------------------------------------------------------------------------------------------
# shared ViT pieces (timm-style key names: patch_embed.proj, norm1, attn.qkv, attn.proj, norm2,
# mlp.fc1, mlp.fc2)


class PatchEmbed(nn.Module):
    """Non-overlapping ``patch x patch`` convolution, flattened to (B, tokens, dim)."""

    def __init__(self, dim: int, patch: int = 16, in_chans: int = 3):
        super().__init__()
        self.proj = nn.Conv2d(in_chans, dim, kernel_size=patch, stride=patch)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x).flatten(2).transpose(1, 2)


class Mlp(nn.Module):
    def __init__(self, dim: int, hidden: int):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.act = nn.GELU()
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(self.act(self.fc1(x)))


class Attention(nn.Module):
    """Only the projections; the attention pattern (asymmetric, cached, with elimination) is the
    caller's, so both trackers share the weights layout."""

    def __init__(self, dim: int, num_heads: int, qkv_bias: bool = True):
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"embed dim {dim} is not divisible by {num_heads} heads")
        self.num_heads = num_heads
        self.qkv = nn.Linear(dim, dim * 3, bias=qkv_bias)
        self.proj = nn.Linear(dim, dim)

    def split(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, N, C) -> q, k, v of shape (B, heads, N, C / heads)."""
        b, n, c = x.shape
        qkv = self.qkv(x).reshape(b, n, 3, self.num_heads, c // self.num_heads).permute(2, 0, 3, 1, 4)
        return qkv[0], qkv[1], qkv[2]

    def merge(self, o: torch.Tensor) -> torch.Tensor:
        """(B, heads, N, d) -> projected (B, N, heads * d)."""
        b, h, n, d = o.shape
        return self.proj(o.transpose(1, 2).reshape(b, n, h * d))


class Block(nn.Module):
    """Pre-norm transformer block, exposed in steps: ``qkv`` (norm1 + projections),
    ``attn_residual`` (output projection + residual) and ``mlp_residual``. OSTrack's candidate
    elimination runs between the last two (as upstream ``CEBlock``)."""

    def __init__(self, dim: int, num_heads: int, mlp_ratio: float, eps: float = 1e-6):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=eps)
        self.attn = Attention(dim, num_heads)
        self.norm2 = nn.LayerNorm(dim, eps=eps)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))

    def qkv(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return self.attn.split(self.norm1(x))

    def attn_residual(self, x: torch.Tensor, o: torch.Tensor) -> torch.Tensor:
        return x + self.attn.merge(o)

    def mlp_residual(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.mlp(self.norm2(x))


def attend(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """softmax(q k^T / sqrt(d)) v (torch's fused kernel; same maths as upstream's explicit form)."""
    return F.scaled_dot_product_attention(q, k, v)


def sincos_pos_embed_2d(dim: int, grid: int) -> np.ndarray:
    """Fixed 2-D sin-cos position embedding (MAE form), (grid*grid, dim), row-major tokens:
    the first half of the channels encodes the column index, the second half the row index,
    each as ``[sin(p w_i), cos(p w_i)]`` with ``w_i = 10000^(-i / (dim/4))``."""
    if dim % 4:
        raise ValueError(f"sin-cos position embedding needs dim divisible by 4, got {dim}")
    omega = 1.0 / 10000 ** (np.arange(dim // 4, dtype=np.float64) / (dim / 4.0))
    rows, cols = np.meshgrid(np.arange(grid, dtype=np.float64), np.arange(grid, dtype=np.float64), indexing="ij")

    def enc(pos: np.ndarray) -> np.ndarray:
        out = np.outer(pos.ravel(), omega)
        return np.concatenate([np.sin(out), np.cos(out)], axis=1)

    return np.concatenate([enc(cols), enc(rows)], axis=1).astype(np.float32)


def _param_from(array: np.ndarray, requires_grad: bool = True) -> nn.Parameter:
    """A parameter created on the current default device (meta included) holding ``array``."""
    p = nn.Parameter(torch.empty(array.shape), requires_grad=requires_grad)
    with torch.no_grad():
        if p.device.type != "meta":
            p.copy_(torch.from_numpy(array))
    return p


# --------------------------------------------------------------------------------------------
# MixFormerV2 (MODELS.md 1.2-1.4)


@dataclass(frozen=True)
class MixFormerV2Config:
    """Network constants; ``feat_sz`` is the number of bins per box coordinate."""

    template_size: int = 112
    search_size: int = 224
    depth: int = 4
    mlp_ratio: float = 1.0
    embed_dim: int = 768
    num_heads: int = 12
    feat_sz: int = 96
    patch_size: int = 16

    @property
    def template_tokens(self) -> int:
        return (self.template_size // self.patch_size) ** 2

    @property
    def search_tokens(self) -> int:
        return (self.search_size // self.patch_size) ** 2


MIXFORMERV2_S = MixFormerV2Config(template_size=112, search_size=224, depth=4, mlp_ratio=1.0)
MIXFORMERV2_B = MixFormerV2Config(template_size=128, search_size=288, depth=8, mlp_ratio=4.0)

REG_TOKENS = 4  # order inside the sequence: left, right, top, bottom (upstream head.py)
_LRTB_TO_LTRB = [0, 2, 1, 3]


class MixFormerV2Backbone(nn.Module):
    """ViT without cls token or final norm; tokens ``[template, online template, search, 4 reg]``.
    Asymmetric mixed attention: template tokens attend to template tokens only, search and reg
    tokens attend to everything. Hence template keys/values never depend on the search image
    and can be cached exactly (:meth:`template_cache`, :meth:`forward_cached`)."""

    def __init__(self, cfg: MixFormerV2Config):
        super().__init__()
        d = cfg.embed_dim
        self.cfg = cfg
        self.patch_embed = PatchEmbed(d, cfg.patch_size)
        self.blocks = nn.ModuleList(Block(d, cfg.num_heads, cfg.mlp_ratio) for _ in range(cfg.depth))
        self.pos_embed_s = _param_from(sincos_pos_embed_2d(d, cfg.search_size // cfg.patch_size)[None], False)
        self.pos_embed_t = _param_from(sincos_pos_embed_2d(d, cfg.template_size // cfg.patch_size)[None], False)
        self.reg_tokens = nn.Parameter(torch.empty(1, REG_TOKENS, d))
        nn.init.trunc_normal_(self.reg_tokens, std=0.02)
        self.pos_embed_reg = nn.Parameter(torch.zeros(1, REG_TOKENS, d))

    def _templates(self, z: torch.Tensor, oz: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.patch_embed(z) + self.pos_embed_t, self.patch_embed(oz) + self.pos_embed_t], dim=1)

    def _search(self, x: torch.Tensor) -> torch.Tensor:
        s = self.patch_embed(x) + self.pos_embed_s
        reg = (self.reg_tokens + self.pos_embed_reg).expand(s.shape[0], -1, -1)
        return torch.cat([s, reg], dim=1)

    def forward(self, z: torch.Tensor, oz: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Full forward; returns the search + reg tokens (B, Ls + 4, D)."""
        h = torch.cat([self._templates(z, oz), self._search(x)], dim=1)
        nt = 2 * self.cfg.template_tokens
        for blk in self.blocks:
            q, k, v = blk.qkv(h)
            o_t = attend(q[:, :, :nt], k[:, :, :nt], v[:, :, :nt])
            o_s = attend(q[:, :, nt:], k, v)
            h = blk.mlp_residual(blk.attn_residual(h, torch.cat([o_t, o_s], dim=2)))
        return h[:, nt:]

    def template_cache(self, z: torch.Tensor, oz: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Keys and values of the template tokens at every block, (B, heads, 2 Lt, d) each."""
        h = self._templates(z, oz)
        cache = []
        for i, blk in enumerate(self.blocks):
            q, k, v = blk.qkv(h)
            cache.append((k, v))
            if i + 1 < len(self.blocks):  # the last block's template outputs are never used
                h = blk.mlp_residual(blk.attn_residual(h, attend(q, k, v)))
        return cache

    def forward_cached(self, x: torch.Tensor, cache: list[tuple[torch.Tensor, torch.Tensor]]) -> torch.Tensor:
        """Search + reg tokens given the template cache; equals :meth:`forward`."""
        if len(cache) != len(self.blocks):
            raise ValueError(f"template cache has {len(cache)} blocks, the network {len(self.blocks)}")
        h = self._search(x)
        for blk, (kt, vt) in zip(self.blocks, cache):
            q, k, v = blk.qkv(h)
            o = attend(q, torch.cat([kt, k], dim=2), torch.cat([vt, v], dim=2))
            h = blk.mlp_residual(blk.attn_residual(h, o))
        return h


class CornerDistributionHead(nn.Module):
    """``MlpHead`` (norm=True, 2 layers): a shared MLP maps each reg token to N logits, the last
    layer a LayerNorm over the N logits; softmax gives one PMF per box side and the side is its
    expectation ``E[j] / N`` (normalised to the search crop, MODELS.md 1.3)."""

    def __init__(self, dim: int, n_bins: int):
        super().__init__()
        self.n_bins = n_bins
        self.layers = nn.Sequential(
            nn.Sequential(nn.Linear(dim, dim), nn.LayerNorm(dim), nn.ReLU()),
            nn.Sequential(nn.Linear(dim, n_bins), nn.LayerNorm(n_bins)),
        )
        self.register_buffer("bins", torch.arange(n_bins, dtype=torch.float32), persistent=False)

    def forward(self, reg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """reg (B, 4, D) in l, r, t, b order -> (box cx, cy, w, h normalised (B, 4),
        PMFs (B, 4, N) in l, t, r, b order)."""
        pmfs = self.layers(reg).softmax(dim=-1)[:, _LRTB_TO_LTRB]
        x1, y1, x2, y2 = ((pmfs * self.bins).sum(dim=-1) / self.n_bins).unbind(dim=-1)
        box = torch.stack([(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1], dim=-1)
        return box, pmfs


class ScoreHead(nn.Module):
    """``MlpScoreDecoder`` (2 layers, no BN): MLP on each reg token, mean over the four -> logit."""

    def __init__(self, dim: int):
        super().__init__()
        self.layers = nn.Sequential(nn.Sequential(nn.Linear(dim, dim), nn.ReLU()), nn.Linear(dim, 1))

    def forward(self, reg: torch.Tensor) -> torch.Tensor:
        return self.layers(reg).mean(dim=1).view(-1)


class MixFormerV2Net(nn.Module):
    """MixFormerV2 (backbone + distribution corner head + MLP score head). Every forward returns
    ``(box (B, 4) cx cy w h in [0, 1) of the search crop, score logit (B,), PMFs (B, 4, N))``."""

    def __init__(self, cfg: MixFormerV2Config = MIXFORMERV2_S):
        super().__init__()
        self.cfg = cfg
        self.backbone = MixFormerV2Backbone(cfg)
        self.box_head = CornerDistributionHead(cfg.embed_dim, cfg.feat_sz)
        self.score_head = ScoreHead(cfg.embed_dim)

    def _heads(self, tokens: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        reg = tokens[:, -REG_TOKENS:]
        box, pmfs = self.box_head(reg)
        return box, self.score_head(reg), pmfs

    def forward(self, z: torch.Tensor, oz: torch.Tensor, x: torch.Tensor):
        return self._heads(self.backbone(z, oz, x))

    def encode_templates(self, z: torch.Tensor, oz: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return self.backbone.template_cache(z, oz)

    def forward_search(self, x: torch.Tensor, cache: list[tuple[torch.Tensor, torch.Tensor]]):
        return self._heads(self.backbone.forward_cached(x, cache))


# --------------------------------------------------------------------------------------------
# OSTrack (MODELS.md 2.1-2.3)


@dataclass(frozen=True)
class OSTrackConfig:
    """vitb_256_mae_ce by default. ``pretrain_grid`` is the MAE grid of the unused ``pos_embed``
    kept in the checkpoint (14 -> 1 + 196 positions)."""

    template_size: int = 128
    search_size: int = 256
    depth: int = 12
    embed_dim: int = 768
    num_heads: int = 12
    mlp_ratio: float = 4.0
    patch_size: int = 16
    ce_loc: tuple[int, ...] = (3, 6, 9)
    ce_keep_ratio: tuple[float, ...] = (0.7, 0.7, 0.7)
    head_channels: int = 256
    pretrain_grid: int = 14

    @property
    def feat_sz(self) -> int:
        return self.search_size // self.patch_size

    @property
    def template_grid(self) -> int:
        return self.template_size // self.patch_size


OSTRACK_256 = OSTrackConfig()


def _ce_keep_count(keep_ratio: float, n: int) -> int:
    return math.ceil(keep_ratio * n)


def eliminate_candidates(h: torch.Tensor, attn: torch.Tensor, n_template: int, keep_ratio: float,
                         index: torch.Tensor, query: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Candidate elimination (OSTrack, ``CE_TEMPLATE_RANGE = CTR_POINT``): rank the search tokens
    by the head-averaged attention they receive from template query token ``query`` and keep the
    ``ceil(keep_ratio * Ls)`` best. Returns the new tokens, the kept global indices and the
    removed ones (None when nothing is removed)."""
    n_search = h.shape[1] - n_template
    keep = _ce_keep_count(keep_ratio, n_search)
    if keep >= n_search:
        return h, index, None
    score = attn[:, :, query, n_template:].mean(dim=1)  # (B, Ls)
    order = torch.sort(score, dim=1, descending=True).indices
    kept, removed = order[:, :keep], order[:, keep:]
    tokens = h[:, n_template:].gather(1, kept.unsqueeze(-1).expand(-1, -1, h.shape[-1]))
    return torch.cat([h[:, :n_template], tokens], dim=1), index.gather(1, kept), index.gather(1, removed)


class OSTrackBackbone(nn.Module):
    """ViT-B/16 one-stream backbone with candidate elimination (``VisionTransformerCE``): joint
    attention over ``[template, search]``; after attention in the blocks of ``ce_loc`` the least
    attended search tokens are dropped; after the final norm the dropped tokens come back as
    zero vectors so the search map is complete again."""

    def __init__(self, cfg: OSTrackConfig):
        super().__init__()
        if len(cfg.ce_loc) != len(cfg.ce_keep_ratio):
            raise ValueError(f"ce_loc {cfg.ce_loc} and ce_keep_ratio {cfg.ce_keep_ratio} differ in length")
        d = cfg.embed_dim
        self.cfg = cfg
        self.cls_token = nn.Parameter(torch.zeros(1, 1, d))  # in the checkpoint, unused at inference
        self.pos_embed = nn.Parameter(torch.zeros(1, cfg.pretrain_grid ** 2 + 1, d))  # idem
        self.pos_embed_z = nn.Parameter(torch.empty(1, cfg.template_grid ** 2, d))
        self.pos_embed_x = nn.Parameter(torch.empty(1, cfg.feat_sz ** 2, d))
        for p in (self.pos_embed, self.pos_embed_z, self.pos_embed_x):
            nn.init.trunc_normal_(p, std=0.02)
        self.patch_embed = PatchEmbed(d, cfg.patch_size)
        self.blocks = nn.ModuleList(Block(d, cfg.num_heads, cfg.mlp_ratio) for _ in range(cfg.depth))
        self.norm = nn.LayerNorm(d, eps=1e-6)
        ratios = [1.0] * cfg.depth
        for loc, r in zip(cfg.ce_loc, cfg.ce_keep_ratio):
            ratios[loc] = float(r)
        self.keep_ratios = tuple(ratios)
        g = cfg.template_grid
        self.ce_query = ((g - 1) // 2) * g + (g - 1) // 2  # CTR_POINT: (3, 3) -> 27 on 8 x 8

    def forward(self, z: torch.Tensor, x: torch.Tensor, keep_ratio: float | None = None
                ) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """Search feature map (B, D, F, F) and the removed search indices per CE block.
        ``keep_ratio`` overrides the ratio of the CE blocks (1.0 disables elimination)."""
        zt = self.patch_embed(z) + self.pos_embed_z
        xt = self.patch_embed(x) + self.pos_embed_x
        b, nt, ns = zt.shape[0], zt.shape[1], xt.shape[1]
        h = torch.cat([zt, xt], dim=1)
        index = torch.arange(ns, device=h.device).unsqueeze(0).expand(b, -1)
        removed = []
        for blk, ratio in zip(self.blocks, self.keep_ratios):
            if ratio < 1.0 and keep_ratio is not None:
                ratio = keep_ratio
            q, k, v = blk.qkv(h)
            h = blk.attn_residual(h, attend(q, k, v))
            if ratio < 1.0:
                # only the CE query's attention row is needed for the ranking
                qc = q[:, :, self.ce_query:self.ce_query + 1]
                row = ((qc @ k.transpose(-2, -1)) * q.shape[-1] ** -0.5).softmax(dim=-1)
                h, index, gone = eliminate_candidates(h, row, nt, ratio, index, query=0)
                if gone is not None:
                    removed.append(gone)
            h = blk.mlp_residual(h)
        h = self.norm(h)
        xs = h[:, nt:]
        full = xs.new_zeros(b, ns, xs.shape[-1]).scatter(1, index.unsqueeze(-1).expand(-1, -1, xs.shape[-1]), xs)
        fs = self.cfg.feat_sz
        return full.transpose(1, 2).reshape(b, -1, fs, fs), removed


def _conv_bn_relu(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1, bias=True), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class CenterHead(nn.Module):
    """``CenterPredictor``: three branches (ctr, offset, size) of four 3x3 conv-BN-ReLU layers
    (C, C/2, C/4, C/8 channels) and a 1x1 conv. Returns ``score`` = clamp(sigmoid) (B, 1, F, F),
    ``size`` = clamp(sigmoid) (B, 2, F, F) as a fraction of the search crop, ``offset`` (B, 2, F, F)
    in cells."""

    BRANCHES = (("ctr", 1), ("offset", 2), ("size", 2))

    def __init__(self, dim: int, channels: int = 256):
        super().__init__()
        widths = [dim, channels, channels // 2, channels // 4, channels // 8]
        for name, out in self.BRANCHES:
            for i in range(4):
                self.add_module(f"conv{i + 1}_{name}", _conv_bn_relu(widths[i], widths[i + 1]))
            self.add_module(f"conv5_{name}", nn.Conv2d(widths[4], out, kernel_size=1))

    def _branch(self, name: str, x: torch.Tensor) -> torch.Tensor:
        for i in range(1, 6):
            x = getattr(self, f"conv{i}_{name}")(x)
        return x

    def forward(self, feat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        score = self._branch("ctr", feat).sigmoid().clamp(1e-4, 1 - 1e-4)
        size = self._branch("size", feat).sigmoid().clamp(1e-4, 1 - 1e-4)
        offset = self._branch("offset", feat)
        return score, size, offset


class OSTrackNet(nn.Module):
    """OSTrack: ``forward(template, search, keep_ratio=None) -> (score, size, offset)`` maps of
    the centre head; ``removed_indexes`` after a forward lists the CE-removed search tokens."""

    def __init__(self, cfg: OSTrackConfig = OSTRACK_256):
        super().__init__()
        self.cfg = cfg
        self.backbone = OSTrackBackbone(cfg)
        self.box_head = CenterHead(cfg.embed_dim, cfg.head_channels)
        self.removed_indexes: list[torch.Tensor] = []

    def forward(self, z: torch.Tensor, x: torch.Tensor, keep_ratio: float | None = None):
        feat, self.removed_indexes = self.backbone(z, x, keep_ratio)
        return self.box_head(feat)


# --------------------------------------------------------------------------------------------
# checkpoints


class CheckpointError(RuntimeError):
    """A checkpoint file could not be loaded into the network; the message names the file, the
    expected official checkpoint and what differs."""


@dataclass(frozen=True)
class OfficialCheckpoint:
    """What an official checkpoint is called and where it is published."""

    model: str
    file_name: str
    source: str


class _Stub:
    """Stand-in for a class of a module that is not importable (e.g. the upstream trainer's
    ``lib.train.admin`` settings stored next to the weights); it just keeps its state."""

    def __init__(self, *args, **kwargs):
        self._args, self._kwargs = args, kwargs

    def __setstate__(self, state):
        self._state = state


class _LenientUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        try:
            return super().find_class(module, name)
        except (ImportError, AttributeError):
            return type(name, (_Stub,), {"__module__": module})


_lenient_pickle = types.ModuleType("mata_lenient_pickle")
_lenient_pickle.Unpickler = _LenientUnpickler  # type: ignore[attr-defined]
_lenient_pickle.load = lambda f, **kw: _LenientUnpickler(f, **kw).load()  # type: ignore[attr-defined]


def _first_line(e: BaseException) -> str:
    """The informative part of a torch.load error (its unpickler detail, else the first line)."""
    text = str(e).strip()
    detail = re.search(r"WeightsUnpickler error:\s*(.+)", text)
    line = detail.group(1).strip() if detail else (text.splitlines()[0] if text else "")
    return f"{type(e).__name__}: {line}"[:300]


def read_state_dict(path: str | Path, official: OfficialCheckpoint, trust_pickle: bool = False) -> dict:
    """The ``state_dict`` of a checkpoint file: a trainer dict ``{'net': state_dict, ...}`` (as the
    upstream trainers write it) or a bare state_dict.

    Safe by default: ``torch.load(weights_only=True)`` only rebuilds tensors and plain containers.
    ``trust_pickle`` allows full unpickling of a trusted legacy file; classes whose modules are not
    importable (the upstream trainer's settings objects) are replaced by inert stubs."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(
            f"{official.model} checkpoint not found: {path}. Expected the official "
            f"'{official.file_name}', published at {official.source}.")
    try:
        if trust_pickle:
            obj = torch.load(path, map_location="cpu", weights_only=False, pickle_module=_lenient_pickle)
        else:
            obj = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        found = re.search(r"Unsupported global: GLOBAL (\S+)", str(e))
        if not found:  # e.g. a truncated or foreign file
            raise CheckpointError(
                f"{path}: not a readable torch checkpoint ({_first_line(e)}). Expected the official "
                f"'{official.file_name}' for {official.model}, published at {official.source}.") from e
        raise CheckpointError(
            f"{path}: weights-only loading refused this file, it pickles Python objects besides "
            f"tensors (first: {found.group(1)}). If you trust it (e.g. the official '{official.file_name}' "
            f"from {official.source}), set the tracker parameter trust_pickle: true.") from e
    except Exception as e:  # corrupt or not a torch file
        raise CheckpointError(
            f"{path}: not a readable torch checkpoint ({_first_line(e)}). Expected the official "
            f"'{official.file_name}' for {official.model}, published at {official.source}.") from e
    if isinstance(obj, Mapping) and "net" in obj:
        sd = obj["net"]
    else:
        sd = obj
    if not isinstance(sd, Mapping) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        keys = list(obj)[:8] if isinstance(obj, Mapping) else type(obj).__name__
        raise CheckpointError(
            f"{path}: expected a trainer checkpoint {{'net': state_dict, ...}} or a bare state_dict of "
            f"tensors, found {keys}. Expected the official '{official.file_name}' ({official.source}).")
    sd = dict(sd)
    if sd and all(k.startswith("module.") for k in sd):  # saved from a DataParallel wrapper
        sd = {k[len("module."):]: v for k, v in sd.items()}
    return sd


def load_checkpoint(model: nn.Module, path: str | Path, official: OfficialCheckpoint,
                    trust_pickle: bool = False) -> None:
    """Load ``path`` into ``model`` with strict key and shape matching; a mismatch raises
    :class:`CheckpointError` listing missing/unexpected keys and shape differences."""
    model.load_state_dict(matching_state_dict(model, path, official, trust_pickle), strict=True)


def matching_state_dict(model: nn.Module, path: str | Path, official: OfficialCheckpoint,
                        trust_pickle: bool = False) -> dict:
    """The state_dict of ``path``, checked key by key and shape by shape against ``model`` (which
    may be on the ``meta`` device: the preflight checks a file without materialising a network)."""
    sd = read_state_dict(path, official, trust_pickle)
    own = model.state_dict()
    missing = [k for k in own if k not in sd]
    unexpected = [k for k in sd if k not in own]
    shapes = [f"{k}: file {tuple(sd[k].shape)} vs model {tuple(own[k].shape)}"
              for k in own if k in sd and tuple(sd[k].shape) != tuple(own[k].shape)]
    if missing or unexpected or shapes:
        def few(items: list[str]) -> str:
            return ", ".join(items[:6]) + (f" (+{len(items) - 6} more)" if len(items) > 6 else "")
        parts = [f"{len(missing)} missing key(s): {few(missing)}" if missing else "",
                 f"{len(unexpected)} unexpected key(s): {few(unexpected)}" if unexpected else "",
                 f"{len(shapes)} shape mismatch(es): {few(shapes)}" if shapes else ""]
        raise CheckpointError(
            f"{path} does not match {official.model} (expected the official '{official.file_name}', "
            f"published at {official.source}): " + "; ".join(p for p in parts if p))
    return sd
