"""MixFormerV2 (S: 112/224, depth 4; B: 128/288, depth 8) in PyTorch, with the paper's PMF window
confidence (section 2.1, eq. score) and the score-gated template update (section 2.1, last
paragraph), loading the official checkpoints (MODELS.md section 1).

Per frame: a square search crop of side ``ceil(sqrt(w h) * search_factor)`` around the last box
(or around the MATA prior), RGB + ImageNet normalisation, the network gives four 96-bin PMFs
(left, top, right, bottom) whose expectations are the box, and the MLP score; the box is mapped
back to the image and clipped (margin 10 px) as upstream.

Confidence: ``window`` = ``min_c`` of the probability mass in ``2 round(alpha N / 2) + 1`` bins
around each PMF's mode, truncated at the edges (alpha = 0.03 -> 3 bins of 96); ``mlp`` = the
original sigmoid score. The chosen one is reported and gates the template update. ``extra`` also
holds both scores, each side's PMF standard deviation in image pixels (``sigma_left`` ...) and the
search square cropped (``search_x`` ...).

Template update (``template_update``): ``threshold`` (paper) replaces the online template by the
crop at the new box whenever the score exceeds ``tau_template``; ``interval`` is upstream's policy
(keep the best crop scoring above the threshold within each interval, install it every
``update_interval`` frames, fall back to the initial template); ``none`` keeps the initial one.

Torch is imported only when the tracker is used (it is an optional extra).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Mapping

import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Box, TrackerOutput

from .backends import check_weights_and_device
from .crop import check_crop_factors, clip_box, map_box_back, sample_target, search_region, usable_prior
from .model_files import exported_graphs
from .window_score import check_window_alpha, pmf_window_score_min

SOURCE = "https://github.com/MCG-NJU/MixFormerV2 (README, model zoo: Google Drive / NJU Box links)"


@dataclass(frozen=True)
class Variant:
    """One released MixFormerV2 model: its network constants, checkpoint name and env var."""

    label: str
    config: str  # name of the config constant in vit.py
    file_name: str
    env_var: str


VARIANTS = {
    "S": Variant("MixFormerV2-S", "MIXFORMERV2_S", "mixformerv2_small.pth.tar", "MATA_MIXFORMERV2_S"),
    "B": Variant("MixFormerV2-B", "MIXFORMERV2_B", "mixformerv2_base.pth.tar", "MATA_MIXFORMERV2_B"),
}


class CheckpointNotFound(FileNotFoundError):
    """No checkpoint configured or found; the message names the file and where it is published."""


def checkpoint_path(configured: str | None, env_var: str, file_name: str, source: str) -> Path:
    """The checkpoint to load: the YAML parameter ``checkpoint``, else ``$env_var``. A folder means
    ``<folder>/<file_name>``. Nothing is downloaded."""
    raw = configured or os.environ.get(env_var)
    if not raw:
        raise CheckpointNotFound(
            f"no checkpoint given: set the tracker parameter 'checkpoint' or ${env_var} to the official "
            f"'{file_name}' (published at {source}; not downloaded at run time), or set random_weights: "
            f"true for timing/plumbing runs.")
    path = Path(raw).expanduser()
    if path.is_dir():
        path = path / file_name
    if not path.is_file():
        origin = "parameter 'checkpoint'" if configured else f"${env_var}"
        raise CheckpointNotFound(
            f"checkpoint {path} (from {origin}) does not exist; expected the official '{file_name}', "
            f"published at {source}.")
    return path


class TemplateSchedule:
    """When to capture a template crop and when to install it as the online template.

    ``step(score) -> (capture, commit)`` for each tracked frame: *capture* means crop a template
    at the new box now; *commit* means the online template becomes the latest capture of the
    period (or, in ``interval`` mode with no capture in the interval, the initial template).
    """

    def __init__(self, mode: Literal["threshold", "interval", "none"], tau: float, interval: int = 200):
        if mode not in ("threshold", "interval", "none"):
            raise ValueError(f"template_update must be threshold, interval or none, got {mode!r}")
        if mode == "interval" and interval < 1:
            raise ValueError(f"update_interval must be >= 1, got {interval}")
        self.mode, self.tau, self.interval = mode, float(tau), int(interval)
        self.frame = 0
        self.best = -math.inf

    def step(self, score: float) -> tuple[bool, bool]:
        self.frame += 1
        if self.mode == "none":
            return False, False
        if self.mode == "threshold":  # paper: update only when the confidence exceeds tau_template
            ok = score > self.tau
            return ok, ok
        capture = score > self.tau and score > self.best  # upstream MixFormerOnline.track
        if capture:
            self.best = score
        commit = self.frame % self.interval == 0
        if commit:
            self.best = -math.inf
        return capture, commit


class MixFormerV2:
    """MixFormerV2 S/B (PyTorch): PMF window-score confidence, score-gated template update."""

    name = "mixformerv2"
    label = "MixFormerV2"  # display name in reports

    @staticmethod
    def explainable_score(params: Mapping[str, Any]) -> bool:
        """Reports (paper Table 3 "Score"): does this configuration use the explainable PMF
        window score?"""
        return params.get("confidence", MixFormerV2.Params().confidence) == "window"

    @dataclass(frozen=True)
    class Params:
        variant: Literal["S", "B"] = param("S", "S = 112/224 depth 4 (mixformerv2_small), B = 128/288 depth 8 (mixformerv2_base)")
        checkpoint: str | None = param(None, "official .pth.tar (or a folder holding it); else $MATA_MIXFORMERV2_S / $MATA_MIXFORMERV2_B")
        trust_pickle: bool = param(False, "allow full unpickling of a trusted legacy checkpoint (default: weights only)")
        random_weights: bool = param(False, "no checkpoint: seeded random weights (timing and plumbing only)")
        seed: int = param(0, "seed of the random weights")
        device: str = param("cpu", "torch device: cpu, cuda, cuda:1, ...; onnxruntime: cpu, cuda or tensorrt")
        threads: int = param(0, "torch CPU threads (0 = leave torch's setting)")
        backend: Literal["torch", "onnxruntime", "tensorrt"] = param("torch", "torch, or the graphs of `mata-eval export mixformerv2` (folder `onnx`) on onnxruntime / a TensorRT engine")
        onnx: str | None = param(None, "folder written by `mata-eval export mixformerv2` (onnxruntime / tensorrt backends)")
        search_factor: float = param(4.5, "search crop side / sqrt(w h) (yaml TEST 4.5; upstream scripts use 4.4-5.0)")
        template_factor: float = param(2.0, "template crop side / sqrt(w h)")
        confidence: Literal["window", "mlp"] = param("window", "reported and gating score: paper's PMF window score or the original MLP score")
        window_alpha: float = param(0.03, "window score: 2 round(alpha N / 2) + 1 bins around each mode (paper: 0.03)")
        tau_template: float = param(0.5, "template update only when the gating score exceeds this")
        template_update: Literal["threshold", "interval", "none"] = param("threshold", "threshold (paper), interval (upstream best-of-interval) or none")
        update_interval: int = param(200, "interval mode: frames between installs (upstream: 200 LaSOT, 25 video demo)")
        template_cache: bool = param(True, "cache the template keys/values (exact); recomputed only when the template changes")

        def __post_init__(self) -> None:
            """Ranges, checked when the experiment is loaded (not in a sequence's first frame)."""
            if self.variant not in VARIANTS:
                raise ValueError(f"mixformerv2: variant: expected one of {', '.join(VARIANTS)}, got {self.variant!r}")
            check_crop_factors("mixformerv2", self)
            check_weights_and_device("mixformerv2", self)
            check_window_alpha("mixformerv2", self.window_alpha, "the PMF's bins")
            if not math.isfinite(self.tau_template):
                raise ValueError(f"mixformerv2: tau_template: expected a finite number, got {self.tau_template!r}")
            if self.update_interval < 1:
                raise ValueError(f"mixformerv2: update_interval: expected >= 1, got {self.update_interval!r}")

    def __init__(self, params: "MixFormerV2.Params | None" = None, network: Any = None):
        """``network``: an already built ``vit.MixFormerV2Net`` (tests, custom sizes); otherwise it
        is built from ``variant`` and loaded from the checkpoint on first use."""
        self.params = p = params or self.Params()
        self.variant = VARIANTS[p.variant]
        self._net = network
        self._path = None
        if p.backend != "torch" and network is None and not p.onnx:
            raise ValueError(f"the {p.backend} backend needs `onnx`: the folder of `mata-eval export mixformerv2`")
        if p.backend != "torch" and network is None:   # the export fits, before any frame
            _check_export(p)
        if network is None and not p.random_weights and p.backend == "torch":  # fail early, naming the file
            self._path = checkpoint_path(p.checkpoint, self.variant.env_var, self.variant.file_name, SOURCE)
        self._schedule = TemplateSchedule(p.template_update, p.tau_template, p.update_interval)
        self._state: Box | None = None

    @classmethod
    def model_files(cls, params: "MixFormerV2.Params") -> dict[str, Path]:
        """The weight files these parameters read: the checkpoint (the YAML path, else
        $MATA_MIXFORMERV2_S / _B), or the graphs of the export; a run's manifest records them and
        their sha256. Nothing with random weights."""
        if params.backend != "torch":
            return exported_graphs(params.onnx, "mixformerv2") if params.onnx else {}
        if params.random_weights or params.variant not in VARIANTS:
            return {}
        v = VARIANTS[params.variant]
        return {"checkpoint": checkpoint_path(params.checkpoint, v.env_var, v.file_name, SOURCE)}

    def check(self) -> None:
        """Preflight: the backend and device can run here and the checkpoint's keys and shapes
        are the variant's (not torch's error, or the loader's, on the first frame)."""
        from .backends import check_device, check_exported_graphs

        p = self.params
        check_device(p.backend, p.device)
        if self._path is not None:
            self._checkpoint()
        if p.backend != "torch" and self._net is None:
            check_exported_graphs(p.onnx, "mixformerv2", ("template", "search") if p.template_cache else ("full",))

    def _checkpoint(self, net=None) -> dict:
        """The checkpoint's state_dict, checked key by key and shape by shape against ``net`` (by
        default the variant's network on the ``meta`` device); a checkpoint of the other variant
        is named with the ``variant:`` to set."""
        from .vit import CheckpointError

        p = self.params
        try:
            return _matching_state_dict(self._path, p.variant, p.trust_pickle, net)
        except CheckpointError as exc:
            fits = [k for k in VARIANTS if k != p.variant and _fits(self._path, k, p.trust_pickle)]
            if fits:
                raise CheckpointError(f"{exc}. It is a {VARIANTS[fits[0]].label} checkpoint: set variant: "
                                      f"{fits[0]}") from None
            raise

    # -- network ---------------------------------------------------------------------------

    def network(self):
        """The torch network (built and loaded on first call)."""
        if self._net is None and self.params.backend != "torch":
            from .backends import ExportedMixFormerV2

            p = self.params
            self._net = ExportedMixFormerV2(p.onnx, p.backend, p.device, p.threads)
            self._net.open(*(("template", "search") if p.template_cache else ("full",)))
        if self._net is None:
            import torch

            from . import vit

            p = self.params
            if p.threads > 0:
                torch.set_num_threads(p.threads)
            cfg = getattr(vit, self.variant.config)
            if p.random_weights:
                with torch.random.fork_rng(devices=[]):  # seeded, without touching the global RNG
                    torch.manual_seed(p.seed)
                    net = vit.MixFormerV2Net(cfg)
            else:
                with torch.device("meta"):
                    net = vit.MixFormerV2Net(cfg)
                net = net.to_empty(device="cpu")
                net.box_head.bins = torch.arange(cfg.feat_sz, dtype=torch.float32)
                net.load_state_dict(self._checkpoint(net), strict=True)
            self._net = net
        self._net.eval().to(self.params.device)
        return self._net

    # -- tracking ----------------------------------------------------------------------------

    def _crop(self, image: np.ndarray, box: Box, factor: float, size: int, center=None):
        from .vit import image_to_tensor

        patch, resize_factor = sample_target(image, box, factor, size, center=center)
        return image_to_tensor(patch, self.params.device if self.params.backend == "torch" else "cpu"), resize_factor

    def _set_online(self, online) -> None:
        import torch

        self._online = online
        if self.params.template_cache:
            with torch.inference_mode():
                self._cache = self._net.encode_templates(self._template, online)

    def initialize(self, image: np.ndarray, box: Box) -> None:
        _check_image(image)
        if not box.is_valid:
            raise ValueError(f"initial box must be finite with positive size, got {box}")
        net = self.network()
        self._template, _ = self._crop(image, box, self.params.template_factor, net.cfg.template_size)
        self._candidate = None
        self._schedule = TemplateSchedule(self.params.template_update, self.params.tau_template,
                                          self.params.update_interval)
        self._set_online(self._template)
        self._state = box

    def track(self, image: np.ndarray, prior: tuple[float, float] | None = None) -> TrackerOutput:
        import torch

        if self._state is None:
            raise RuntimeError("MixFormerV2.track called before initialize")
        _check_image(image)
        p, net = self.params, self._net
        size = net.cfg.search_size
        prior = usable_prior(prior, self._state.w, self._state.h, *image.shape[:2])
        center = self._state.center if prior is None else prior
        region = search_region(self._state, p.search_factor, center)
        x, resize_factor = self._crop(image, self._state, p.search_factor, size, center=center)
        with torch.inference_mode():
            if p.template_cache:
                box_n, logit, pmfs_t = net.forward_search(x, self._cache)
            else:
                box_n, logit, pmfs_t = net(self._template, self._online, x)
        pmfs = pmfs_t[0].double().cpu().numpy()
        pred = box_n[0].double().cpu().numpy() * size / resize_factor
        h, w = image.shape[:2]
        self._state = clip_box(map_box_back(pred, center, size, resize_factor), h, w, margin=10)
        mlp_score = float(torch.sigmoid(logit[0]).item())
        window_score = pmf_window_score_min(pmfs, p.window_alpha)
        score = window_score if p.confidence == "window" else mlp_score
        capture, commit = self._schedule.step(score)
        if capture:
            self._candidate, _ = self._crop(image, self._state, p.template_factor, net.cfg.template_size)
        if commit:
            self._set_online(self._candidate if self._candidate is not None else self._template)
            self._candidate = None
        extra = {"mlp_score": mlp_score, "window_score": window_score, "template_updated": float(commit), **region}
        extra.update(zip(("sigma_left", "sigma_top", "sigma_right", "sigma_bottom"),
                         pmf_sigmas_px(pmfs, size / resize_factor)))
        return TrackerOutput(box=self._state, confidence=score, pmfs=pmfs, extra=extra)


def _matching_state_dict(path: Path, variant: str, trust_pickle: bool, net=None) -> dict:
    """``vit.matching_state_dict`` against ``net``, by default ``variant``'s on the ``meta`` device."""
    import torch

    from . import vit

    v = VARIANTS[variant]
    if net is None:
        with torch.device("meta"):
            net = vit.MixFormerV2Net(getattr(vit, v.config))
    return vit.matching_state_dict(net, path, vit.OfficialCheckpoint(v.label, v.file_name, SOURCE), trust_pickle)


def _fits(path: Path, variant: str, trust_pickle: bool) -> bool:
    """Whether the checkpoint has exactly ``variant``'s keys and shapes."""
    from .vit import CheckpointError

    try:
        _matching_state_dict(path, variant, trust_pickle)
    except CheckpointError:
        return False
    return True


def _check_export(p: MixFormerV2.Params) -> None:
    """The export in ``p.onnx`` is of ``p.variant`` and has the graphs ``template_cache`` runs
    (the two-graph form with the cache, the full graph without); else a ValueError saying what to
    set or export."""
    from mata_eval.deploy.export import MANIFEST, read_manifest

    doc, where = read_manifest(p.onnx, "mixformerv2"), Path(p.onnx).expanduser() / MANIFEST
    exported = doc.get("config", {}).get("variant")
    if exported is not None and exported != p.variant:
        raise ValueError(f"{where}: an export of variant {exported}, but the tracker says variant: {p.variant}; set "
                         f"variant: {exported} or export variant {p.variant} (mata-eval export mixformerv2 --variant "
                         f"{p.variant})")
    has = set(doc.get("graphs", {}))
    needs, form = (("template", "search"), "two-graph") if p.template_cache else (("full",), "full")
    if not set(needs) <= has:
        raise ValueError(f"{where}: template_cache: {str(p.template_cache).lower()} runs the {' and '.join(needs)} "
                         f"graph(s), but this export has {', '.join(sorted(has)) or 'none'}; set template_cache: "
                         f"{str(not p.template_cache).lower()} or export them (mata-eval export mixformerv2 --form "
                         f"{form} or both)")


def pmf_sigmas_px(pmfs: np.ndarray, crop_side_px: float) -> list[float]:
    """Standard deviation of each side's PMF in image pixels: ``sqrt(Var_j[p]) * crop / N`` (bin
    width = crop side / N at image scale; MODELS.md 1.6, a cheap per-corner measurement noise)."""
    p = np.asarray(pmfs, dtype=np.float64)
    j = np.arange(p.shape[-1], dtype=np.float64)
    mean = (p * j).sum(axis=-1)
    var = np.maximum((p * j * j).sum(axis=-1) - mean * mean, 0.0)
    return [float(v) for v in np.sqrt(var) * crop_side_px / p.shape[-1]]


def _check_image(image: np.ndarray) -> None:
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError("expected a BGR uint8 image of shape (H, W, 3), got "
                         f"{getattr(image, 'dtype', type(image).__name__)} {getattr(image, 'shape', '')}")


@hookimpl
def mata_eval_trackers():
    return [MixFormerV2]
