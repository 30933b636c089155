"""The value types blocks exchange (boxes, tracker outputs, motions, estimates, stamps).

Public plugin API: plugins import from here. The code lives in :mod:`mata_eval.core.types`;
this module re-exports it so that ``from mata_eval.types import ...`` stays stable."""

from .core.types import Box, Estimate, Frame, FrameImage, Motion, Stamped, TrackerOutput, derived, within_image

__all__ = ["Box", "Estimate", "Frame", "FrameImage", "Motion", "Stamped", "TrackerOutput", "derived", "within_image"]
