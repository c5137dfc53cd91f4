"""The one-view benchmark (``python -m lisa_hand.bench oneview``) on the demo's second unseen hand,
the one whose one-view fit stopped 10 cm too near before the depth restarts."""

from __future__ import annotations

import json

import pytest

from lisa_hand.bench import oneview
from lisa_hand.utils.threads import cpu_threads


@pytest.fixture(scope="module")
def second_hand(tmp_path_factory):
    with cpu_threads(1):
        return oneview.unseen_hands(tmp_path_factory.mktemp("oneview"), 2)[1]


def test_depth_restarts_fix_the_second_demo_hand(second_hand, tmp_path):
    with cpu_threads(1):
        results = oneview.run_oneview_benchmark([second_hand], log=lambda line: None)
    (row,) = results["per_hand"]
    # Without the restarts: about 10 cm too near (96 mm MPJPE); with them: about 2 cm.
    assert row["reference_mpjpe_mm"] > 60.0 and row["reference_wrist_depth_mm"] < -60.0
    assert row["mpjpe_mm"] < 35.0 and abs(row["wrist_depth_mm"]) < 35.0
    assert results["mpjpe_mm"] == row["mpjpe_mm"]
    assert results["reference_wrist_depth_mm"] == abs(row["reference_wrist_depth_mm"])
    truth = json.loads((second_hand / "params.json").read_text())
    assert len(truth["keypoints"]) == 21


@pytest.mark.parametrize("argv, message", [(["--hands", "0"], "--hands must be >= 1"),
                                           (["--threads", "0"], "--threads must be >= 1")])
def test_bad_arguments_are_refused(argv, message):
    with pytest.raises(ValueError, match=message):
        oneview.main(argv)
