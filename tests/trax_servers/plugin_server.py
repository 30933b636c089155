"""A TraX server around one of mata-eval's in-process tracker plugins, run as its own process:
``python plugin_server.py nanotrack|vittrack [key=value ...]`` (parameters as the plugin's
Params, e.g. ``model=/path/vittrack.onnx``).

Reads MATA's search centre from the frame properties ``prior_x``, ``prior_y`` and reports the
plugin's confidence as the ``confidence`` property, as a prior-aware TraX tracker would.
"""

from __future__ import annotations

import sys

import cv2
from trax import Image, ImageChannel, MemoryImage, Region, Server, TraxStatus
from trax.region import Rectangle

from mata_eval.types import Box
from mata_eval_plugins.trackers.nanotrack import NanoTrack
from mata_eval_plugins.trackers.vittrack import VitTrack

PLUGINS = {"nanotrack": NanoTrack, "vittrack": VitTrack}


def bgr(image):
    """The frame as the plugin expects it (BGR), from a memory (RGB) or path image."""
    if isinstance(image, MemoryImage):
        return cv2.cvtColor(image.array(), cv2.COLOR_RGB2BGR)
    return cv2.imread(image.path(), cv2.IMREAD_COLOR)


def main(argv: list[str]) -> None:
    cls = PLUGINS[argv[0]]
    params = cls.Params(**dict(arg.split("=", 1) for arg in argv[1:]))
    tracker = cls(params)
    with Server([Region.RECTANGLE], [Image.MEMORY, Image.PATH], [ImageChannel.COLOR],
                tracker_name=f"mata-eval {argv[0]}") as server:
        while True:
            request = server.wait()
            if request.type == TraxStatus.QUIT:
                return
            image = bgr(request.image[ImageChannel.COLOR])
            if request.type == TraxStatus.INITIALIZE:
                region = request.objects[0][0]
                box = Box(*region.bounds())
                tracker.initialize(image, box)
                server.status([(Rectangle.create(box.x, box.y, box.w, box.h), {})])
                continue
            props = request.properties.dict()
            prior = (float(props["prior_x"]), float(props["prior_y"])) if "prior_x" in props else None
            out = tracker.track(image, prior)
            b = out.box
            server.status([(Rectangle.create(b.x, b.y, b.w, b.h), {"confidence": repr(out.confidence)})])


if __name__ == "__main__":
    main(sys.argv[1:])
