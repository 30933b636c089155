"""A TraX tracker whose behaviour the tests choose, to check what crosses the protocol and what
happens when a tracker misbehaves. Each answer is a box of the initial size centred on the
``prior_x``, ``prior_y`` frame properties when they are sent (else the initial box), with the
CRC-32 of the frame's BGR bytes as the property ``crc``.

    python scripted_server.py [--images path|memory] [--confidence C] [--pid-file F]
                              [--crash-at K] [--hang-at K] [--special-at K] [--exit-at-init]

``--exit-at-init`` ends cleanly at ``initialize`` without an answer, as a C server on libtrax's
single-object calls does when it receives the object list.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
import zlib

import cv2
from trax import ImageChannel, MemoryImage, Region, Server, TraxStatus
from trax.region import Rectangle, Special


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--images", choices=["path", "memory"], nargs="+", default=["path", "memory"])
    ap.add_argument("--confidence")
    ap.add_argument("--pid-file")
    ap.add_argument("--crash-at", type=int)
    ap.add_argument("--hang-at", type=int)
    ap.add_argument("--special-at", type=int)
    ap.add_argument("--exit-at-init", action="store_true")
    args = ap.parse_args()
    if args.pid_file:
        with open(args.pid_file, "w") as f:
            f.write(str(os.getpid()))
    box, k = None, 0
    with Server([Region.RECTANGLE], args.images, [ImageChannel.COLOR]) as server:
        while True:
            request = server.wait()
            if request.type == TraxStatus.QUIT:
                return
            image = request.image[ImageChannel.COLOR]
            bgr = (cv2.cvtColor(image.array(), cv2.COLOR_RGB2BGR) if isinstance(image, MemoryImage)
                   else cv2.imread(image.path(), cv2.IMREAD_COLOR))
            props = {"crc": zlib.crc32(bgr.tobytes()), "image": "memory" if isinstance(image, MemoryImage) else "path"}
            if args.confidence is not None:
                props["confidence"] = args.confidence
            if request.type == TraxStatus.INITIALIZE:
                if args.exit_at_init:
                    sys.exit(0)
                box = request.objects[0][0].bounds()
                server.status([(Rectangle.create(*box), props)])
                continue
            k += 1
            if k == args.crash_at:
                print(f"scripted tracker: crashing at frame {k}", file=sys.stderr, flush=True)
                sys.exit(3)
            if k == args.hang_at:
                child = subprocess.Popen(["sleep", "600"])
                print(f"scripted tracker: hanging at frame {k}, child {child.pid}", file=sys.stderr, flush=True)
                time.sleep(600)
            if k == args.special_at:
                server.status([(Special.create(0), props)])
                continue
            p = request.properties.dict()
            x, y, w, h = box
            if "prior_x" in p:
                x, y = float(p["prior_x"]) - w / 2, float(p["prior_y"]) - h / 2
            server.status([(Rectangle.create(x, y, w, h), props)])


if __name__ == "__main__":
    main()
