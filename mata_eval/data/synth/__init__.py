"""Synthetic UAV sequences with exact ego-motion (``mata-eval synth``).

A textured ground plane (:mod:`.texture`) is seen by a pinhole camera that follows a target the
way a UAV operator would (:mod:`.motion`: lagging pursuit with a wandering framing error and
re-framing pans, matched to UAV123's image-plane motion; yaw, tilt, zoom and roll changes, sudden
manoeuvres and, on request, out-of-view spells; ``motion: legacy`` keeps generator version 3's
tight pursuit). Vehicle- or person-like sprites
move on the ground; distractors of the same look move near the target; tree canopies occlude it.
Every frame is ``cv2.warpPerspective`` of the ground with the plane-to-image homography ``G_k``
(:mod:`.render`), so the true inter-frame homography ``H_k = G_k G_{k-1}^-1`` (paper section
2.2's block B target) is known exactly.

- :mod:`.spec`: what determines a sequence (:class:`SequenceSpec`, :func:`suite_specs`);
- :mod:`.motion`: target, distractor and camera motion (the plan of a sequence);
- :mod:`.texture`: the ground texture and the sprites;
- :mod:`.render`: frames, ground truth and true homographies (:func:`render_sequence`);
- :mod:`.attributes`: the 12 UAV123 attribute flags from what was generated;
- :mod:`.writer`: the suite on disk in the UAV123 layout (:func:`write_suite`).
"""

from .attributes import ABSENT_BELOW, UAV123_ATTRIBUTES, attribute_flags
from .render import RenderedSequence, ground_texture, render_sequence
from .spec import GENERATOR_VERSION, MOTIONS, SCENARIOS, SequenceSpec, make_spec, suite_specs
from .writer import SUITE_MARKER, load_true_homographies, read_suite_info, write_suite

__all__ = ["ABSENT_BELOW", "GENERATOR_VERSION", "MOTIONS", "SCENARIOS", "SUITE_MARKER", "UAV123_ATTRIBUTES",
           "RenderedSequence", "SequenceSpec", "attribute_flags", "ground_texture", "load_true_homographies",
           "make_spec", "read_suite_info", "render_sequence", "suite_specs", "write_suite"]
