"""CPU milliseconds per frame of MixFormerV2-S, MixFormerV2-B and OSTrack-256 (PyTorch, fp32,
batch 1, random weights: latency does not depend on the weights), full versus cached forward.

    python benchmarks/transformers.py [--models S B ostrack] [--n 20] [--warmup 3] [--threads 2]

For each model, the median over ``n`` interleaved runs of:
- MixFormerV2: the full forward (template + online template + search, the baseline measured in the
  same run) and the search-only forward with the template keys/values cached (exact, MODELS.md
  6.3); their ratio; the template encoding paid at each template update; and one whole
  ``track()`` call on a 1280x720 frame (crop, preprocessing, cached forward, window score);
- OSTrack: candidate elimination on (as trained, keep 0.7 at blocks 3, 6, 9) against off (keep
  1.0, the baseline); no cache is possible (its template tokens attend to the search region);
  and one whole ``track()`` call.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from mata_eval.types import Box
from mata_eval_plugins.trackers.mixformerv2 import MixFormerV2
from mata_eval_plugins.trackers.ostrack import OSTrack


def median_ms(fns: dict, n: int, warmup: int) -> dict:
    """Median milliseconds of each function; the functions are run interleaved (one of each per
    round) so that load from other processes affects all of them alike."""
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    times: dict = {k: [] for k in fns}
    for _ in range(n):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) * 1e3 for k, v in times.items()}


def frame(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (720, 1280, 3), dtype=np.uint8)


def bench_mixformer(variant: str, n: int, warmup: int) -> None:
    trk = MixFormerV2(MixFormerV2.Params(variant=variant, random_weights=True, seed=0))
    net = trk.network()
    cfg = net.cfg
    g = torch.Generator().manual_seed(0)
    z = torch.randn(1, 3, cfg.template_size, cfg.template_size, generator=g)
    x = torch.randn(1, 3, cfg.search_size, cfg.search_size, generator=g)
    with torch.inference_mode():
        cache = net.encode_templates(z, z)
        ms = median_ms({"full": lambda: net(z, z, x), "cached": lambda: net.forward_search(x, cache),
                        "encode": lambda: net.encode_templates(z, z)}, n, warmup)
        full, cached, encode = ms["full"], ms["cached"], ms["encode"]
        err = max(float((a - b).abs().max()) for a, b in zip(net(z, z, x), net.forward_search(x, cache)))
    img = frame()
    trk.initialize(img, Box(600, 330, 60, 50))
    track = median_ms({"track": lambda: trk.track(img)}, n, warmup)["track"]
    params = sum(p.numel() for p in net.parameters()) / 1e6
    print(f"MixFormerV2-{variant} ({cfg.template_size}/{cfg.search_size}, depth {cfg.depth}, {params:.2f} M params)")
    print(f"  full forward        {full:8.1f} ms   (baseline)")
    print(f"  cached forward      {cached:8.1f} ms   x{full / cached:.2f} faster, max |diff| {err:.1e}")
    print(f"  template encoding   {encode:8.1f} ms   (paid once per template update)")
    print(f"  track() per frame   {track:8.1f} ms   (1280x720, cached, window score)")


def bench_ostrack(n: int, warmup: int) -> None:
    trk = OSTrack(OSTrack.Params(random_weights=True, seed=0))
    net = trk.network()
    g = torch.Generator().manual_seed(0)
    z = torch.randn(1, 3, 128, 128, generator=g)
    x = torch.randn(1, 3, 256, 256, generator=g)
    with torch.inference_mode():
        ms = median_ms({"off": lambda: net(z, x, 1.0), "on": lambda: net(z, x)}, n, warmup)
        off, on = ms["off"], ms["on"]
    img = frame()
    trk.initialize(img, Box(600, 330, 60, 50))
    track = median_ms({"track": lambda: trk.track(img)}, n, warmup)["track"]
    params = sum(p.numel() for p in net.parameters()) / 1e6
    print(f"OSTrack-256 CE ({params:.2f} M params)")
    print(f"  full forward, CE off {off:7.1f} ms   (baseline)")
    print(f"  full forward, CE on  {on:7.1f} ms   x{off / on:.2f} faster (keep 0.7 at blocks 3, 6, 9)")
    print("  cached forward           n/a      (template tokens attend to the search region)")
    print(f"  track() per frame    {track:7.1f} ms   (1280x720, CE on)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=["S", "B", "ostrack"], choices=["S", "B", "ostrack"])
    ap.add_argument("--n", type=int, default=20, help="timed runs; the median is reported")
    ap.add_argument("--warmup", type=int, default=3, help="untimed runs first")
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch default)")
    args = ap.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} CPU threads, fp32, batch 1")
    for m in args.models:
        if m == "ostrack":
            bench_ostrack(args.n, args.warmup)
        else:
            bench_mixformer(m, args.n, args.warmup)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
