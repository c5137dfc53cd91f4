"""What every fitter's stages share: the one diagnostics type and its history's columns."""

from __future__ import annotations

import math

from lisa_hand.fitting.stages import StageReport, history_columns


def test_a_stage_report_that_did_not_run_has_no_numbers():
    report = StageReport(stage="keypoints")
    assert math.isnan(report.loss) and math.isnan(report.keypoint_error_px)
    assert report.energies == [] and report.history == [] and report.screened_energies == []
    assert report.seconds == 0.0 and report.candidate is None
    assert StageReport(stage="color").history is not report.history  # no shared default


def test_history_columns_of_records():
    history = [
        {"stage": "keypoints", "iteration": 0, "energy": 3.0, "kp_px": 9.0},
        {"stage": "keypoints", "iteration": 1, "energy": 2.0, "kp_px": 4.0},
        {"stage": "color", "iteration": 0, "energy": 1.5, "col": 0.25, "kp_px": 0.5},
    ]
    assert history_columns(history, "keypoints") == {
        "iteration": [0.0, 1.0], "energy": [3.0, 2.0], "kp_px": [9.0, 4.0]}
    assert history_columns(history, "color") == {
        "iteration": [0.0], "energy": [1.5], "col": [0.25], "kp_px": [0.5]}
    assert history_columns(history) == {
        "iteration": [0.0, 1.0, 0.0], "energy": [3.0, 2.0, 1.5], "kp_px": [9.0, 4.0, 0.5],
        "col": [0.25]}
    assert history_columns(history, "field") == {}
