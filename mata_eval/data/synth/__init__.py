"""Synthetic UAV sequences with exact ego-motion (``mata-eval synth``)."""

from .render import *  # noqa: F401,F403
from .render import _camera, _write_frames, ground_texture  # noqa: F401
