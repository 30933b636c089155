"""OSTrack (vitb_256_mae_ce: template 128, search 256, candidate elimination keeping 0.7 of the
search tokens at blocks 3, 6 and 9, centre head) in PyTorch, loading the official
``OSTrack_ep0300.pth.tar`` (MODELS.md section 2).

Per frame: a square search crop of side ``ceil(sqrt(w h) * 4)`` around the last box (or the MATA
prior), RGB + ImageNet normalisation; the centre head's 16x16 score map is multiplied by a
centred Hann window, its argmax cell gives the box ``((i + offset) / 16, size)`` in crop units,
which is mapped back to the image and clipped (margin 10 px) as upstream. OSTrack has a fixed
template (no update, paper section 2.1) and keeps its own confidence: the peak of the sigmoid
score map before the Hann window.

Torch is imported only when the tracker is used (it is an optional extra).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from mata_eval.hooks import hookimpl
from mata_eval.params import param
from mata_eval.types import Box, TrackerOutput

from .backends import check_weights_and_device
from .crop import check_crop_factors, clip_box, map_box_back, sample_target, search_region, usable_prior
from .mixformerv2 import _check_image, checkpoint_path
from .model_files import exported_graphs

SOURCE = "https://github.com/botaoye/OSTrack (README, model zoo: vitb_256_mae_ce_32x4_ep300, Google Drive)"
FILE_NAME = "OSTrack_ep0300.pth.tar"
ENV_VAR = "MATA_OSTRACK"


def hann_window_2d(n: int) -> np.ndarray:
    """Upstream ``hann2d(centered=True)``: outer product of ``0.5 (1 - cos(2 pi k / (n + 1)))``,
    k = 1..n (no zero at the borders)."""
    k = np.arange(1, n + 1, dtype=np.float64)
    w = 0.5 * (1.0 - np.cos(2.0 * np.pi * k / (n + 1)))
    return np.outer(w, w)


def center_head_box(response: np.ndarray, size_map: np.ndarray, offset_map: np.ndarray) -> np.ndarray:
    """``(cx, cy, w, h)`` normalised to the search crop from the argmax cell of ``response``
    (F, F): ``cx = (ix + offset_x) / F``, ``cy = (iy + offset_y) / F``, ``(w, h) = size`` there
    (upstream ``CenterPredictor.cal_bbox``; first cell in row-major order on ties)."""
    f = response.shape[-1]
    iy, ix = np.unravel_index(int(np.argmax(response)), response.shape)
    return np.array([(ix + offset_map[0, iy, ix]) / f, (iy + offset_map[1, iy, ix]) / f,
                     size_map[0, iy, ix], size_map[1, iy, ix]], dtype=np.float64)


class OSTrack:
    """OSTrack-256 with candidate elimination (PyTorch); fixed template, sigmoid peak confidence."""

    name = "ostrack"
    label = "OSTrack"  # display name in reports

    @dataclass(frozen=True)
    class Params:
        checkpoint: str | None = param(None, f"official {FILE_NAME} (or a folder holding it); else ${ENV_VAR}")
        trust_pickle: bool = param(False, "allow full unpickling of a trusted legacy checkpoint (default: weights only)")
        random_weights: bool = param(False, "no checkpoint: seeded random weights (timing and plumbing only)")
        seed: int = param(0, "seed of the random weights")
        device: str = param("cpu", "torch device: cpu, cuda, cuda:1, ...; onnxruntime: cpu, cuda or tensorrt")
        threads: int = param(0, "torch CPU threads (0 = leave torch's setting)")
        backend: Literal["torch", "onnxruntime", "tensorrt"] = param("torch", "torch, or the graph of `mata-eval export ostrack` (folder `onnx`) on onnxruntime / a TensorRT engine")
        onnx: str | None = param(None, "folder written by `mata-eval export ostrack` (onnxruntime / tensorrt backends)")
        search_factor: float = param(4.0, "search crop side / sqrt(w h)")
        template_factor: float = param(2.0, "template crop side / sqrt(w h)")
        ce_keep_ratio: float | None = param(None, "override the keep ratio of the CE blocks (null = 0.7 as trained; 1.0 disables CE)")
        hann_window: bool = param(True, "multiply the score map by the centred Hann window before the argmax (upstream)")

        def __post_init__(self) -> None:
            """Ranges, checked when the experiment is loaded (not in a sequence's first frame)."""
            check_crop_factors("ostrack", self)
            check_weights_and_device("ostrack", self)
            if self.ce_keep_ratio is not None and not 0.0 < self.ce_keep_ratio <= 1.0:
                raise ValueError(f"ostrack: ce_keep_ratio: expected a number in (0, 1] (1 disables candidate "
                                 f"elimination) or null, got {self.ce_keep_ratio!r}")

    def __init__(self, params: "OSTrack.Params | None" = None, network: Any = None):
        """``network``: an already built ``vit.OSTrackNet`` (tests, custom sizes); otherwise the
        official configuration is built and loaded from the checkpoint on first use."""
        self.params = p = params or self.Params()
        self._net = network
        self._path = None
        if p.backend != "torch" and network is None and not p.onnx:
            raise ValueError(f"the {p.backend} backend needs `onnx`: the folder of `mata-eval export ostrack`")
        if p.backend != "torch" and network is None:   # the export fits, before any frame
            _check_export(p)
        if network is None and not p.random_weights and p.backend == "torch":
            self._path = checkpoint_path(p.checkpoint, ENV_VAR, FILE_NAME, SOURCE)
        self._state: Box | None = None

    @classmethod
    def model_files(cls, params: "OSTrack.Params") -> dict[str, Path]:
        """The weight files these parameters read: the checkpoint (the YAML path, else
        $MATA_OSTRACK), or the graph of the export; a run's manifest records them and their
        sha256. Nothing with random weights."""
        if params.backend != "torch":
            return exported_graphs(params.onnx, "ostrack") if params.onnx else {}
        if params.random_weights:
            return {}
        return {"checkpoint": checkpoint_path(params.checkpoint, ENV_VAR, FILE_NAME, SOURCE)}

    def check(self) -> None:
        """Preflight: the backend and device can run here and the checkpoint's keys and shapes
        are OSTrack-256's (not torch's error, or the loader's, on the first frame)."""
        from .backends import check_device, check_exported_graphs

        check_device(self.params.backend, self.params.device)
        if self.params.backend != "torch" and self._net is None:
            check_exported_graphs(self.params.onnx, "ostrack", ("full",))
        if self._path is not None:
            import torch

            from . import vit

            with torch.device("meta"):
                net = vit.OSTrackNet(vit.OSTRACK_256)
            vit.matching_state_dict(net, self._path, _official(), trust_pickle=self.params.trust_pickle)

    def network(self):
        """The torch network (built and loaded on first call)."""
        if self._net is None and self.params.backend != "torch":
            from .backends import ExportedOSTrack

            p = self.params
            self._net = ExportedOSTrack(p.onnx, p.backend, p.device, p.threads)
        if self._net is None:
            import torch

            from . import vit

            p = self.params
            if p.threads > 0:
                torch.set_num_threads(p.threads)
            if p.random_weights:
                with torch.random.fork_rng(devices=[]):  # seeded, without touching the global RNG
                    torch.manual_seed(p.seed)
                    net = vit.OSTrackNet(vit.OSTRACK_256)
            else:
                with torch.device("meta"):
                    net = vit.OSTrackNet(vit.OSTRACK_256)
                net = net.to_empty(device="cpu")
                vit.load_checkpoint(net, self._path, _official(), trust_pickle=p.trust_pickle)
            self._net = net
        self._net.eval().to(self.params.device)
        return self._net

    def _tensor_device(self) -> str:
        return self.params.device if self.params.backend == "torch" else "cpu"

    def initialize(self, image: np.ndarray, box: Box) -> None:
        from .vit import image_to_tensor

        _check_image(image)
        if not box.is_valid:
            raise ValueError(f"initial box must be finite with positive size, got {box}")
        net = self.network()
        patch, _ = sample_target(image, box, self.params.template_factor, net.cfg.template_size)
        self._template = image_to_tensor(patch, self._tensor_device())
        self._hann = hann_window_2d(net.cfg.feat_sz)
        self._state = box

    def track(self, image: np.ndarray, prior: tuple[float, float] | None = None) -> TrackerOutput:
        import torch

        from .vit import image_to_tensor

        if self._state is None:
            raise RuntimeError("OSTrack.track called before initialize")
        _check_image(image)
        p, net = self.params, self._net
        size = net.cfg.search_size
        prior = usable_prior(prior, self._state.w, self._state.h, *image.shape[:2])
        center = self._state.center if prior is None else prior
        region = search_region(self._state, p.search_factor, center)
        patch, resize_factor = sample_target(image, self._state, p.search_factor, size, center=center)
        with torch.inference_mode():
            score, size_map, offset = net(self._template, image_to_tensor(patch, self._tensor_device()), p.ce_keep_ratio)
        score_map = score[0, 0].double().cpu().numpy()
        response = score_map * self._hann if p.hann_window else score_map
        pred = center_head_box(response, size_map[0].double().cpu().numpy(), offset[0].double().cpu().numpy())
        h, w = image.shape[:2]
        self._state = clip_box(map_box_back(pred * size / resize_factor, center, size, resize_factor), h, w, margin=10)
        peak = float(score_map.max())
        return TrackerOutput(box=self._state, confidence=peak, score_map=score_map,
                             extra={"peak_score": peak, "hann_peak": float(response.max()), **region})


def _official():
    from .vit import OfficialCheckpoint

    return OfficialCheckpoint("OSTrack-256 (vitb_256_mae_ce)", FILE_NAME, SOURCE)


def _check_export(p: OSTrack.Params) -> None:
    """The export in ``p.onnx`` is OSTrack's and eliminates candidates at ``ce_keep_ratio`` (baked
    into the graph); else a ValueError saying what to set."""
    from mata_eval.deploy.export import MANIFEST, read_manifest

    baked = read_manifest(p.onnx, "ostrack").get("config", {}).get("ce_keep_ratio") or []
    if p.ce_keep_ratio is not None and any(abs(p.ce_keep_ratio - r) > 1e-9 for r in baked):
        raise ValueError(f"{Path(p.onnx).expanduser() / MANIFEST}: the exported graph eliminates candidates at keep "
                         f"ratio {', '.join(sorted({str(r) for r in baked}))} (fixed in the graph), but the tracker says "
                         f"ce_keep_ratio: {p.ce_keep_ratio}; set ce_keep_ratio: null or backend: torch")


@hookimpl
def mata_eval_trackers():
    return [OSTrack]
