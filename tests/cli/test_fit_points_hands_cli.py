"""``lisa fit-points --hands N`` (a scan of hands that may touch, fitted together): the options
it refuses, each in one line before anything is read or written; an output folder holding
other files, refused before the fit; and what it writes (``OUT/handN/``, ``hands.json``,
``hands.ply``) for the hands the fit returns (the fit itself stubbed: it is
``tests/fitting/test_scan_hands.py``'s)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from lisa_hand.cli import main as cli_main
from lisa_hand.data.meshio import load_mesh
from lisa_hand.skeleton.params import read_params

FAST = ["--no-progress", "--res", "32", "--units", "m"]


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


def lisa(argv: list[str]) -> int:
    """Run ``lisa ARGV`` -> its exit status."""
    with pytest.raises(SystemExit) as info:
        cli_main.main(argv)
    return info.value.code


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The shipped geometric model's mean right hand (palm to a camera at -z) and its mirror
    image as a left hand, 13 mm apart back to back; a scan of them (points on their meshes:
    800 of each, and 10 far from both) as ``scan.npy``."""
    from lisa_hand.inference import mesh_hand
    from lisa_hand.model.trained import load_trained
    from tests.fitting.pair.scene import mean_right_hand, mirrored_left

    root = tmp_path_factory.mktemp("fit_points_hands")
    model = load_trained("geometry_v3", torch.device("cpu"))
    right = mean_right_hand(model)
    right_mesh = mesh_hand(model, right, 32)
    back = float(np.asarray(right_mesh.vertices)[:, 2].max())  # the back's depth, metres
    hands = [right, mirrored_left(right, back + 0.0065)]
    rng = np.random.default_rng(0)
    points = [right_mesh.vertices, mesh_hand(model, hands[1], 32).vertices]
    points = [one[rng.choice(len(one), 800, replace=False)].astype(np.float64) for one in points]
    far = np.array([0.04, 0.4, 0.45]) + rng.normal(0.0, 0.002, (10, 3))
    np.save(root / "scan.npy", np.concatenate(points + [far]))
    labels = np.repeat([0, 1, -1], [800, 800, 10])
    return {"root": root, "model": model, "hands": hands, "labels": labels}


def _refused(capsys, argv: list[str], message: str, out) -> None:
    """``lisa ARGV`` exits with status 2, one line naming ``message``, nothing at ``out``."""
    assert lisa(argv) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("lisa: error: ") and message in error, (argv, error)
    assert "\n" not in error and "Traceback" not in error
    assert not out.exists()


@pytest.mark.parametrize("extra, name", [
    (["--gt", "{root}/scan.npy"], "--gt"),
    (["--hand", "0"], "--hand"),
    (["--refine"], "--refine"),
])
def test_hands_refuses_the_options_of_one_hand(scene, capsys, monkeypatch, extra, name):
    import lisa_hand.fitting.points.io as io

    def never(*args, **kwargs):
        raise AssertionError("fit_hands_file ran")

    monkeypatch.setattr(io, "fit_hands_file", never)
    out = scene["root"] / "refused"
    extra = [value.format(root=scene["root"]) for value in extra]
    _refused(capsys, ["fit-points", str(scene["root"] / "scan.npy"), "--out", str(out),
                      "--hands", "2", *extra, *FAST],
             f"--hands 2 fits every hand of the scan together; {name} is for one hand", out)


def test_hands_must_be_two_or_more(scene, capsys):
    out = scene["root"] / "one"
    assert lisa(["fit-points", str(scene["root"] / "scan.npy"), "--out", str(out),
                 "--hands", "1", *FAST]) == 2
    error = capsys.readouterr().err
    assert "Invalid value for '--hands'" in error, error  # the option's minimum, by typer
    assert "Traceback" not in error and not out.exists()


def test_hands_refuses_an_output_folder_holding_other_files(scene, capsys, monkeypatch):
    import lisa_hand.fitting.points.hands as hands

    def never(*args, **kwargs):
        raise AssertionError("the fit ran")

    monkeypatch.setattr(hands, "fit_scan_hands", never)
    out = scene["root"] / "taken"
    (out / "hand0").mkdir(parents=True)
    (out / "hand0" / "params.json").write_text("{}")  # a previous fit's: allowed
    (out / "notes.txt").write_text("mine")
    assert lisa(["fit-points", str(scene["root"] / "scan.npy"), "--out", str(out),
                 "--hands", "2", *FAST]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("lisa: error: ") and "\n" not in error
    assert "output folder holds files a fit does not write (notes.txt)" in error, error
    assert "hands.json, hands.ply and hand0/, hand1/" in error
    assert sorted(p.name for p in out.iterdir()) == ["hand0", "notes.txt"]
    assert (out / "notes.txt").read_text() == "mine"


def test_hands_writes_each_hand_and_the_pair(scene, capsys, monkeypatch):
    """The fit stubbed to return the true hands and labels: every file of every hand, the pair's
    record and the joined mesh, as the written files themselves say."""
    import lisa_hand.fitting.points.hands as hands_module
    from lisa_hand.fitting.outputs import hand_keypoints_3d

    seen = {}

    def stub(model, points, count, config, *, side, sensor, progress, log):
        seen.update(points=points, count=count, side=side, config=config)
        return hands_module.ScanHands(
            hands=[dataclasses.replace(hand, extra={}) for hand in scene["hands"]],
            labels=scene["labels"].copy(), fits=[], joint=None, seconds=1.0)

    monkeypatch.setattr(hands_module, "fit_scan_hands", stub)
    out = scene["root"] / "pair"
    assert lisa(["fit-points", str(scene["root"] / "scan.npy"), "--out", str(out), "--hands",
                 "2", "--model", "geometry_v3", "--support", "none", *FAST,
                 "--set", "hands.candidate_iters=7", "--set", "hands.joint.iters=0"]) == 0
    printed = capsys.readouterr().out
    assert seen["count"] == 2 and seen["side"] == "auto" and len(seen["points"]) == 1610
    assert seen["config"].hands.candidate_iters == 7 and seen["config"].hands.joint.iters == 0
    assert ("2 hands fitted together in 1 s: hand0 right (800 points), hand1 left (800 points)"
            in printed), printed
    assert sorted(p.name for p in out.iterdir()) == ["hand0", "hand1", "hands.json",
                                                     "hands.ply"]
    meshes, roots = [], []
    for index, (true, side) in enumerate(zip(scene["hands"], ("right", "left"), strict=True)):
        folder = out / f"hand{index}"
        assert sorted(p.name for p in folder.iterdir()) == ["keypoints.json", "mesh.ply",
                                                            "params.json"]
        params = read_params(folder / "params.json")
        assert params.side == side and params.model == "geometry_v3"
        assert torch.allclose(params.pose, true.pose, atol=1e-6)
        assert params.extra["input"]["hand"] == index and params.extra["input"]["hands"] == 2
        assert params.extra["input"]["points"] == 800
        assert params.extra["config"]["fit"]["hands"]["candidate_iters"] == 7
        keypoints = json.loads((folder / "keypoints.json").read_text())
        assert keypoints["side"] == side
        assert np.allclose(keypoints["keypoints_3d"], hand_keypoints_3d(true), atol=1e-6)
        roots.append(np.asarray(keypoints["keypoints_3d"][0]))
        meshes.append(load_mesh(folder / "mesh.ply"))
        assert f"wrote {folder / 'params.json'}" in printed
    record = json.loads((out / "hands.json").read_text())
    assert record["hands"] == [
        {"folder": "hand0", "side": "right", "root_m": np.round(roots[0], 6).tolist()},
        {"folder": "hand1", "side": "left", "root_m": np.round(roots[1], 6).tolist()}]
    assert np.allclose(record["right_to_left_m"], roots[1] - roots[0], atol=2e-6)
    assert record["points_unassigned"] == 10 and record["joint"] is None
    # Back to back 13 mm apart: no overlap.
    assert 0.0 <= record["penetration_mm"] < 0.5
    joined = load_mesh(out / "hands.ply")
    assert joined.num_vertices == sum(mesh.num_vertices for mesh in meshes)
    assert joined.num_faces == sum(mesh.num_faces for mesh in meshes)
