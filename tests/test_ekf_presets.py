"""``preset: paper`` is block C exactly as it was before the improved default (outputs of the
old code on a fixed scenario, stored in tests/data by tests/ekf_reference_scenario.py)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from ekf_reference_scenario import CONFIGS, REFERENCE, run
from mata_eval_plugins.estimators.homography_ekf import PRESETS, HomographyEKF

P = HomographyEKF.Params


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_preset_paper_reproduces_the_old_filter_bit_for_bit(name):
    ref = np.load(REFERENCE)
    boxes, covs = run(HomographyEKF(P(preset="paper", **CONFIGS[name])))
    assert np.array_equal(boxes, ref[f"{name}_boxes"])
    assert np.array_equal(covs, ref[f"{name}_covs"])


def test_the_default_preset_is_not_the_paper_and_yaml_overrides_a_preset_value():
    assert P().resolved().delay == "compensate"
    assert P(preset="paper").resolved().delay == "ignore"
    assert P(preset="paper", delay="compensate").resolved().delay == "compensate"
    boxes, _ = run(HomographyEKF(P()))
    assert not np.array_equal(boxes, np.load(REFERENCE)["ignore_boxes"])
    assert set(PRESETS["paper"]) == set(PRESETS["mata"])


@pytest.mark.parametrize("values, message", [
    ({"tau_ewma": -1.0}, "`tau_ewma` must be in [0, 1]"), ({"tau_diff": 2.0}, "`tau_diff` must be in [0, 1]"),
    ({"chi2_gate": 0.0}, "`follow_consistent` tests a box's innovation against `chi2_gate`, which is 0")])
def test_settings_that_would_quietly_switch_a_test_off_are_refused(values, message):
    """QA pass: a negative tau_ewma / tau_diff disabled the gate without a word, and chi2_gate 0
    left preset mata's follow_consistent inert."""
    from mata_eval.params import build_params

    with pytest.raises(ValueError, match=re.escape(message)):
        build_params(HomographyEKF.Params, values)
    build_params(HomographyEKF.Params, {"chi2_gate": 0.0, "follow_consistent": False})   # what to set instead
    build_params(HomographyEKF.Params, {"preset": "paper", "chi2_gate": 0.0})            # paper: not followed
