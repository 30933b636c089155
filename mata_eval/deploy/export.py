"""``mata-eval export``: the PyTorch trackers to ONNX, with numerical parity against torch checked
on every export (an export whose ONNX Runtime outputs differ from torch beyond the tolerance
fails loudly; the graphs are written under a temporary name and take the place of the folder's
old ones only once all are checked, so a failed or interrupted export leaves the earlier one whole
and no new file behind).

- ``nanotrack``: NanoTrack v2 from ``nanotrackv2.pth`` -> ``nanotrack_backbone_sim.onnx``
  (``input`` -> ``output``, spatial size free: 127 px exemplar and 255 px search) and
  ``nanotrack_head_sim.onnx`` (``input1``, ``input2`` -> ``output1`` cls, ``output2`` loc): the
  names and layout of the published pair, so the ``nanotrack`` tracker loads the folder.
- ``mixformerv2``: one graph ``(template, online_template, search) -> (box, score_logit,
  pmf_left, pmf_top, pmf_right, pmf_bottom)``, and the two-graph form: a template encoder
  ``(template, online_template) -> key_i, value_i`` per block and a search step ``(search,
  key_0, value_0, ...) -> same outputs`` (the exact template K/V cache, MODELS.md 6.3).
- ``ostrack``: ``(template, search) -> (score_map, size_map, offset_map)``; candidate
  elimination uses constant indices (no ``NonZero``), checked on the written graph.

Every export writes ``export.json`` beside the graphs (model, network constants, graph files,
input/output names, parity errors), which the ONNX backends of the trackers read.

Heavy packages (torch, onnx, onnxruntime) are imported inside the functions.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

DEFAULT_OPSET = 17
DEFAULT_ATOL = 1e-4
DEFAULT_RTOL = 1e-3
MANIFEST = "export.json"


class ParityError(RuntimeError):
    """ONNX Runtime's outputs differ from torch's beyond the tolerance."""


@dataclass(frozen=True)
class ExportedGraph:
    """One written graph and its measured parity with torch."""

    role: str
    path: Path
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    max_abs_error: float


@dataclass(frozen=True)
class ExportResult:
    model: str
    out_dir: Path
    graphs: tuple[ExportedGraph, ...]
    config: dict = field(default_factory=dict)

    def graph(self, role: str) -> ExportedGraph:
        return next(g for g in self.graphs if g.role == role)


# --- generic pieces ------------------------------------------------------------------------------

def _require_export_stack() -> None:
    try:
        import onnx  # noqa: F401  (torch's exporter needs it)
        import torch  # noqa: F401
    except ImportError as exc:
        how = ("pip install onnx" if exc.name == "onnx" else
               "pip install torch (on a Jetson, the torch wheel of its JetPack)")
        raise RuntimeError(f"mata-eval export needs torch and onnx ({exc.name} is missing): {how}") from None


def export_module(module: Any, args: Sequence[Any], path: Path, input_names: Sequence[str],
                  output_names: Sequence[str], dynamic_axes: dict | None = None,
                  opset: int = DEFAULT_OPSET) -> Path:
    """``torch.onnx.export`` (TorchScript exporter, ``dynamo=False``: one self-contained file,
    MODELS.md 6.2) of ``module(*args)`` to ``path``, written atomically."""
    import warnings

    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    module.eval()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the legacy exporter's deprecation and tracer warnings
        with torch.no_grad():
            torch.onnx.export(module, tuple(args), str(tmp), dynamo=False, opset_version=opset,
                              input_names=list(input_names), output_names=list(output_names),
                              dynamic_axes=dynamic_axes or None, do_constant_folding=True)
    os.replace(tmp, path)
    return path


def check_parity(module: Any, path: Path, feeds: Sequence[dict[str, np.ndarray]], input_names: Sequence[str],
                 output_names: Sequence[str], atol: float = DEFAULT_ATOL, rtol: float = DEFAULT_RTOL) -> float:
    """Run ``module`` (torch) and ``path`` (ONNX Runtime, CPU) on each feed; return the largest
    absolute difference over all outputs. Raises :class:`ParityError` naming the graph and the
    output when ``|ort - torch| > atol + rtol |torch|`` anywhere."""
    import onnxruntime as ort
    import torch

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    worst = 0.0
    for feed in feeds:
        with torch.no_grad():
            ref = module(*[torch.from_numpy(np.ascontiguousarray(feed[n])) for n in input_names])
        if isinstance(ref, torch.Tensor):
            ref = (ref,)
        got = session.run(list(output_names), {n: feed[n] for n in input_names})
        for name, r, g in zip(output_names, ref, got):
            r = r.detach().cpu().numpy()
            if r.shape != g.shape:
                raise ParityError(f"{_final(path)}: output {name!r} has shape {g.shape} in ONNX Runtime, {r.shape} in torch")
            diff = np.abs(g.astype(np.float64) - r.astype(np.float64))
            worst = max(worst, float(diff.max(initial=0.0)))
            bad = diff > atol + rtol * np.abs(r)
            if bad.any() or not np.all(np.isfinite(g)):
                raise ParityError(f"{_final(path)}: output {name!r} differs from torch by up to {float(diff.max()):.3g} "
                                  f"(tolerance {atol:g} + {rtol:g} |torch|) at {int(bad.sum())} of {bad.size} "
                                  "values; the graph is not a faithful export")
    return worst


def graph_op_types(path: Path) -> set[str]:
    """The operator types of an ONNX graph (main graph and subgraphs)."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    ops: set[str] = set()
    stack = [model.graph]
    while stack:
        g = stack.pop()
        for node in g.node:
            ops.add(node.op_type)
            for attr in node.attribute:
                if attr.g is not None and len(attr.g.node):
                    stack.append(attr.g)
                stack.extend(attr.graphs)
    return ops


def _export_checked(role: str, module: Any, example: dict[str, np.ndarray], parity_feeds: list[dict[str, np.ndarray]],
                    path: Path, input_names: Sequence[str], output_names: Sequence[str], dynamic_axes=None,
                    opset: int = DEFAULT_OPSET, atol: float = DEFAULT_ATOL, rtol: float = DEFAULT_RTOL) -> ExportedGraph:
    import torch

    args = [torch.from_numpy(example[n]) for n in input_names]
    pending = path.with_name(PENDING + path.name)   # the export in the folder stays until this one is checked
    export_module(module, args, pending, input_names, output_names, dynamic_axes, opset)
    err = check_parity(module, pending, [example] + list(parity_feeds), input_names, output_names, atol, rtol)
    return ExportedGraph(role, pending, tuple(input_names), tuple(output_names), err)


#: prefix of a graph written and being checked, renamed to its name with the manifest (:func:`_write_manifest`)
PENDING = ".pending-"


def _final(path: Path) -> Path:
    """The name a pending graph takes once the export is checked (what errors name)."""
    return Path(path).with_name(Path(path).name.removeprefix(PENDING))


@contextlib.contextmanager
def _pending_removed_on_failure(out: Path):
    """Delete the pending graphs in ``out`` when the export fails or is interrupted (Ctrl-C)
    before :func:`_write_manifest` puts them in place."""
    try:
        yield
    except BaseException:
        for p in Path(out).glob(PENDING + "*"):
            p.unlink(missing_ok=True)
        raise


def _write_manifest(result: ExportResult, extra: dict) -> ExportResult:
    """Put the checked graphs of ``result`` in place of the folder's old ones, then write its
    ``export.json`` (a failed export leaves the old export whole); returns ``result`` with the
    graphs' final paths."""
    from ..run import results

    graphs = []
    for g in result.graphs:
        final = _final(g.path)
        os.replace(g.path, final)
        graphs.append(dataclasses.replace(g, path=final))
    result = dataclasses.replace(result, graphs=tuple(graphs))
    doc = {"format": "mata-eval export", "version": 1, "model": result.model, "config": result.config,
           "graphs": {g.role: {"file": g.path.name, "inputs": list(g.inputs), "outputs": list(g.outputs),
                               "max_abs_error_vs_torch": g.max_abs_error} for g in result.graphs},
           "versions": results.package_versions(), **extra}
    results.atomic_write_text(result.out_dir / MANIFEST, json.dumps(doc, indent=1, default=str))
    return result


def read_manifest(folder: str | Path, model: str) -> dict:
    """``export.json`` of an export folder, checked to be of ``model``; errors name the file."""
    path = Path(folder).expanduser() / MANIFEST
    try:
        doc = json.loads(path.read_text())
    except OSError:
        raise FileNotFoundError(f"{path} not found: export the model first (mata-eval export {model} --out {folder})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if doc.get("format") != "mata-eval export" or doc.get("model") != model:
        raise ValueError(f"{path}: expected a mata-eval export of {model!r}, got model {doc.get('model')!r}")
    return doc


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _images(rng: np.random.Generator, shape: tuple[int, ...], pixels: bool) -> np.ndarray:
    """A random crop batch: raw 0..255 pixels, or ImageNet-normalised values (~N(0, 1))."""
    if pixels:
        return rng.uniform(0.0, 255.0, shape).astype(np.float32)
    return rng.standard_normal(shape).astype(np.float32)


# --- NanoTrack -----------------------------------------------------------------------------------

NANOTRACK_FILES = {"backbone": "nanotrack_backbone_sim.onnx", "head": "nanotrack_head_sim.onnx"}


def export_nanotrack(out_dir: str | Path, checkpoint: str | Path | None = None, *, random_weights: bool = False,
                     seed: int = 0, trust_pickle: bool = False, opset: int = DEFAULT_OPSET,
                     atol: float = DEFAULT_ATOL, rtol: float = DEFAULT_RTOL, model: Any = None) -> ExportResult:
    """NanoTrack v2 (.pth, or seeded random weights) -> the backbone + head ONNX pair."""
    _require_export_stack()
    import torch.nn as nn

    from mata_eval_plugins.trackers import nanotrack_torch as nt

    if model is None:
        if checkpoint is not None and random_weights:   # (one of them was silently ignored)
            raise ValueError("nanotrack export: give --checkpoint nanotrackv2.pth or --random-weights, not both")
        if checkpoint is not None:
            checkpoint = nt.checkpoint_file(checkpoint)   # (the folder holding it: export.json names the file)
            model = nt.load_nanotrack_v2(checkpoint, trust_pickle=trust_pickle)
        elif random_weights:
            model = nt.init_random(nt.NanoTrackV2(), seed).eval()
        else:
            raise ValueError("nanotrack export: give --checkpoint nanotrackv2.pth or --random-weights")
    model.eval()

    class Head(nn.Module):
        def __init__(self, head):
            super().__init__()
            self.head = head

        def forward(self, input1, input2):
            return self.head(input1, input2)

    out = Path(out_dir)
    rng = np.random.default_rng(seed)
    search = _images(rng, (1, 3, 255, 255), pixels=True)
    exemplar = _images(rng, (1, 3, 127, 127), pixels=True)
    dyn = {"input": {2: "height", 3: "width"}, "output": {2: "feat_height", 3: "feat_width"}}
    with _pending_removed_on_failure(out):
        backbone = _export_checked("backbone", model.backbone, {"input": search}, [{"input": exemplar}],
                                   out / NANOTRACK_FILES["backbone"], ["input"], ["output"], dyn, opset, atol, rtol)
        import torch

        with torch.no_grad():
            zf = model.backbone(torch.from_numpy(exemplar)).numpy()
            xf = model.backbone(torch.from_numpy(search)).numpy()
        head_feeds = {"input1": zf, "input2": xf}
        head = _export_checked("head", Head(model.ban_head), head_feeds,
                               [{"input1": zf + rng.standard_normal(zf.shape).astype(np.float32),
                                 "input2": xf + rng.standard_normal(xf.shape).astype(np.float32)}],
                               out / NANOTRACK_FILES["head"], ["input1", "input2"], ["output1", "output2"], None,
                               opset, atol, rtol)
        result = ExportResult("nanotrack", out, (backbone, head), {"exemplar_size": 127, "instance_size": 255})
        return _write_manifest(result, {"checkpoint": str(checkpoint) if checkpoint else None,
                                        "checkpoint_sha256": _sha256(Path(checkpoint)) if checkpoint else None,
                                        "random_weights_seed": None if checkpoint else seed})


# --- MixFormerV2 ---------------------------------------------------------------------------------

MIXFORMER_OUTPUTS = ("box", "score_logit", "pmf_left", "pmf_top", "pmf_right", "pmf_bottom")


def mixformer_files(prefix: str) -> dict[str, str]:
    return {"full": f"{prefix}.onnx", "template": f"{prefix}_template.onnx", "search": f"{prefix}_search.onnx"}


def _mixformer_wrappers(net: Any):
    import torch.nn as nn

    def outputs(box, logit, pmfs):
        return (box, logit, pmfs[:, 0], pmfs[:, 1], pmfs[:, 2], pmfs[:, 3])

    class Full(nn.Module):
        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, template, online_template, search):
            return outputs(*self.net(template, online_template, search))

    class Template(nn.Module):
        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, template, online_template):
            return tuple(t for kv in self.net.encode_templates(template, online_template) for t in kv)

    class Search(nn.Module):
        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, search, *kv):
            cache = [(kv[2 * i], kv[2 * i + 1]) for i in range(len(kv) // 2)]
            return outputs(*self.net.forward_search(search, cache))

    return Full(), Template(), Search()


def _load_vit_network(kind: str, variant: str, checkpoint, random_weights: bool, seed: int,
                      trust_pickle: bool) -> tuple[Any, Path | None]:
    """The network to export and the checkpoint file it was loaded from (None: random weights):
    ``checkpoint`` a file or a folder holding the official file, else the tracker's environment
    variable, as the tracker's ``checkpoint:`` reads them."""
    import torch

    from mata_eval_plugins.trackers import vit
    from mata_eval_plugins.trackers.mixformerv2 import checkpoint_path

    if kind == "mixformerv2":
        from mata_eval_plugins.trackers.mixformerv2 import SOURCE, VARIANTS

        if variant not in VARIANTS:
            raise ValueError(f"mixformerv2 export: --variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
        v = VARIANTS[variant]
        cfg, build, official = getattr(vit, v.config), vit.MixFormerV2Net, vit.OfficialCheckpoint(v.label, v.file_name, SOURCE)
        env_var, file_name = v.env_var, v.file_name
    else:
        from mata_eval_plugins.trackers.ostrack import ENV_VAR, FILE_NAME, SOURCE

        cfg, build, official = vit.OSTRACK_256, vit.OSTrackNet, vit.OfficialCheckpoint("OSTrack-256", FILE_NAME, SOURCE)
        env_var, file_name = ENV_VAR, FILE_NAME
    if checkpoint is not None and random_weights:   # (one of them was silently ignored)
        raise ValueError(f"{kind} export: give --checkpoint PATH or --random-weights, not both")
    if random_weights:
        torch.manual_seed(seed)
        return build(cfg).eval(), None
    if checkpoint is None and not os.environ.get(env_var):
        raise ValueError(f"{kind} export: give --checkpoint PATH (or set ${env_var}) or --random-weights")
    path = checkpoint_path(checkpoint, env_var, file_name, SOURCE)
    net = build(cfg)
    vit.load_checkpoint(net, path, official, trust_pickle=trust_pickle)
    return net.eval(), path


def export_mixformerv2(out_dir: str | Path, checkpoint: str | Path | None = None, *, variant: str = "S",
                       random_weights: bool = False, seed: int = 0, trust_pickle: bool = False,
                       forms: Sequence[str] = ("full", "two_graph"), network: Any = None, prefix: str | None = None,
                       opset: int = DEFAULT_OPSET, atol: float = DEFAULT_ATOL, rtol: float = DEFAULT_RTOL) -> ExportResult:
    """MixFormerV2 -> the single graph (``full``) and/or the template-encoder + search-step pair
    (``two_graph``); the four PMFs are outputs. ``network``: an already built ``MixFormerV2Net``."""
    _require_export_stack()
    import torch

    if network is None:
        network, checkpoint = _load_vit_network("mixformerv2", variant, checkpoint, random_weights, seed, trust_pickle)
    net = network
    net.eval()
    cfg = net.cfg
    prefix = prefix or f"mixformerv2_{variant}"
    files = mixformer_files(prefix)
    out = Path(out_dir)
    rng = np.random.default_rng(seed)

    def feed():
        return {"template": _images(rng, (1, 3, cfg.template_size, cfg.template_size), False),
                "online_template": _images(rng, (1, 3, cfg.template_size, cfg.template_size), False),
                "search": _images(rng, (1, 3, cfg.search_size, cfg.search_size), False)}

    example, other = feed(), feed()
    full_m, template_m, search_m = _mixformer_wrappers(net)
    with _pending_removed_on_failure(out):
        graphs = []
        if "full" in forms:
            graphs.append(_export_checked("full", full_m, example, [other], out / files["full"],
                                          ["template", "online_template", "search"], MIXFORMER_OUTPUTS, None,
                                          opset, atol, rtol))
        if "two_graph" in forms:
            kv_names = [f"{kind}_{i}" for i in range(cfg.depth) for kind in ("key", "value")]
            graphs.append(_export_checked("template", template_m, example, [other], out / files["template"],
                                          ["template", "online_template"], kv_names, None, opset, atol, rtol))

            def search_feed(f):
                with torch.no_grad():
                    kv = template_m(torch.from_numpy(f["template"]), torch.from_numpy(f["online_template"]))
                return {"search": f["search"], **{n: t.numpy() for n, t in zip(kv_names, kv)}}

            s_example, s_other = search_feed(example), search_feed(other)
            graphs.append(_export_checked("search", search_m, s_example, [s_other], out / files["search"],
                                          ["search"] + kv_names, MIXFORMER_OUTPUTS, None, opset, atol, rtol))
            # The chain template graph -> search graph, both in ONNX Runtime, equals the torch full forward.
            _check_chain(net, graphs[-2].path, graphs[-1].path, other, kv_names, atol, rtol)
        if not graphs:
            raise ValueError(f"mixformerv2 export: forms must include 'full' and/or 'two_graph', got {list(forms)}")
        config = {k: getattr(cfg, k)
                  for k in ("template_size", "search_size", "depth", "feat_sz", "embed_dim", "num_heads")}
        result = ExportResult("mixformerv2", out, tuple(graphs), {**config, "variant": variant})
        return _write_manifest(result, {"checkpoint": str(checkpoint) if checkpoint else None,
                                        "checkpoint_sha256": _sha256(Path(checkpoint)) if checkpoint else None,
                                        "random_weights_seed": None if checkpoint else seed})


def _check_chain(net: Any, template_path: Path, search_path: Path, feed: dict, kv_names: list[str],
                 atol: float, rtol: float) -> None:
    import onnxruntime as ort
    import torch

    t = ort.InferenceSession(str(template_path), providers=["CPUExecutionProvider"])
    s = ort.InferenceSession(str(search_path), providers=["CPUExecutionProvider"])
    kv = t.run(kv_names, {"template": feed["template"], "online_template": feed["online_template"]})
    got = s.run(list(MIXFORMER_OUTPUTS), {"search": feed["search"], **dict(zip(kv_names, kv))})
    with torch.no_grad():
        box, logit, pmfs = net(*(torch.from_numpy(feed[n]) for n in ("template", "online_template", "search")))
    ref = [box, logit] + [pmfs[:, i] for i in range(4)]
    for name, r, g in zip(MIXFORMER_OUTPUTS, ref, got):
        r = r.numpy()
        if not np.allclose(g, r, atol=atol, rtol=rtol):
            raise ParityError(f"{_final(search_path)}: the template graph + search graph chain differs from the torch full "
                              f"forward on {name!r} by up to {float(np.abs(g - r).max()):.3g}")


# --- OSTrack -------------------------------------------------------------------------------------

OSTRACK_OUTPUTS = ("score_map", "size_map", "offset_map")
DATA_DEPENDENT_OPS = {"NonZero", "Loop", "If"}


def export_ostrack(out_dir: str | Path, checkpoint: str | Path | None = None, *, random_weights: bool = False,
                   seed: int = 0, trust_pickle: bool = False, network: Any = None, name: str = "ostrack_256",
                   opset: int = DEFAULT_OPSET, atol: float = DEFAULT_ATOL, rtol: float = DEFAULT_RTOL) -> ExportResult:
    """OSTrack (candidate elimination at the trained keep ratio) -> one graph. Candidate
    elimination selects its query with a constant index and ranks with TopK/Gather/Scatter, so
    the graph has no data-dependent-shape op; a ``NonZero`` (or control flow) fails the export."""
    _require_export_stack()
    import torch.nn as nn

    if network is None:
        network, checkpoint = _load_vit_network("ostrack", "", checkpoint, random_weights, seed, trust_pickle)
    net = network
    net.eval()
    cfg = net.cfg

    class Wrapper(nn.Module):
        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, template, search):
            return self.net(template, search)

    out = Path(out_dir)
    rng = np.random.default_rng(seed)

    def feed():
        return {"template": _images(rng, (1, 3, cfg.template_size, cfg.template_size), False),
                "search": _images(rng, (1, 3, cfg.search_size, cfg.search_size), False)}

    with _pending_removed_on_failure(out):
        graph = _export_checked("full", Wrapper(), feed(), [feed()], out / f"{name}.onnx", ["template", "search"],
                                OSTRACK_OUTPUTS, None, opset, atol, rtol)
        bad = graph_op_types(graph.path) & DATA_DEPENDENT_OPS
        if bad:
            raise ParityError(f"{_final(graph.path)}: the graph contains data-dependent ops {sorted(bad)}; candidate elimination "
                              "must use constant indices")
        config = {"template_size": cfg.template_size, "search_size": cfg.search_size, "feat_sz": cfg.feat_sz,
                  "ce_keep_ratio": list(cfg.ce_keep_ratio), "ce_loc": list(cfg.ce_loc)}
        result = ExportResult("ostrack", out, (graph,), config)
        return _write_manifest(result, {"checkpoint": str(checkpoint) if checkpoint else None,
                                        "checkpoint_sha256": _sha256(Path(checkpoint)) if checkpoint else None,
                                        "random_weights_seed": None if checkpoint else seed})
