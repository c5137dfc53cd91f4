"""``lisa fit-points``: the three output files, and one-line errors for bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lisa_hand.cli import fit_points as fit_points_cli
from lisa_hand.cli import main as cli_main
from lisa_hand.data.meshio import load_mesh, save_mesh
from lisa_hand.data.scans import ScanConfig
from lisa_hand.model.trained import export_trained
from lisa_hand.skeleton.params import read_params
from lisa_hand.utils.threads import cpu_threads
from tests.fitting.test_points import scan_of, surface, tiny_model, true_hand

FAST_ARGS = ["--iterations", "15", "--restarts", "1", "--res", "40", "--no-progress",
             "--side", "right"]  # one fit, not both sides (--side auto, the default)


@pytest.fixture(scope="module")
def lisa():
    """``lisa_hand.cli.main.main`` with the fit-points verb (registered here until main.py
    lists it), returning the exit status."""
    names = [command.name for command in cli_main.app.registered_commands]
    if "fit-points" not in names:
        fit_points_cli.register(cli_main.app)

    def run(argv: list[str]) -> int:
        with pytest.raises(SystemExit) as info:
            cli_main.main(argv)
        return info.value.code

    return run


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A tiny colour model, a scan of its own surface (with normals) and the true mesh."""
    root = tmp_path_factory.mktemp("fit_points")
    with cpu_threads(1):
        model = tiny_model(color=True)
        truth = true_hand(model, seed=2)
        points, normals, _ = scan_of(model, truth, ScanConfig(num_points=600), seed=2)
        export_trained(model, root / "tiny.pt")
        np.savez(root / "scan.npz", points=points, normals=normals)
        save_mesh(root / "truth.ply", surface(model, truth))
    return root, points


def test_writes_params_mesh_and_metrics(lisa, files, capsys):
    root, points = files
    out = root / "out"
    assert lisa(["fit-points", str(root / "scan.npz"), "--out", str(out), "--model",
                 str(root / "tiny.pt"), "--gt", str(root / "truth.ply"), *FAST_ARGS]) == 0
    printed = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "metrics.json",
                                                     "params.json", "preview.png"]
    # This tiny model's blob hand runs on past its wrist: the scan points there are left out
    # and said so.
    beyond = read_params(out / "params.json").extra["fit"]["beyond_wrist_points"]
    counted = f"{len(points) - beyond} of {len(points)}" if beyond else f"{len(points)}"
    assert f"fitted {counted} points" in printed and "wrote" in printed
    assert (f"{beyond} points lie beyond the wrist" in printed) == (beyond > 0)
    params = read_params(out / "params.json")
    # A scan from all round: --viewpoint auto finds no sensor, and says nothing of it unless
    # the fit covers little of the hand (where the user may want to know why).
    found = params.extra["fit"]["viewpoint_estimate"]
    assert not found["one_view"] and "viewpoint_m" not in params.extra["input"]
    covered = params.extra["fit"]["coverage"] >= 2.0 / 3.0
    assert ("not one view" in printed or "too few to find" in printed) == (not covered), printed
    assert params.side == "right" and params.betas is not None and params.betas.shape == (10,)
    assert params.color_code is not None and params.color_code.shape == (8,)
    assert params.model.endswith("tiny.pt")
    assert params.extra["fit"]["num_points"] + beyond == len(points)
    assert params.extra["input"]["unit"] == "m"
    mesh = load_mesh(out / "mesh.ply")
    assert mesh.num_vertices > 100 and mesh.colors is not None
    assert mesh.skin_weights is not None and mesh.skin_weights.shape[1] == 16
    assert np.allclose(mesh.skin_weights.sum(1), 1.0, atol=1e-4)
    metrics = json.loads((out / "metrics.json").read_text())
    assert list(metrics) == ["v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm",
                             "v2v_scan_to_recon_mm", "v2s_scan_to_recon_mm"]
    assert all(0.0 < value < 20.0 for value in metrics.values())
    assert not [p for p in root.iterdir() if p.name.startswith(".out.")]  # no staging left


def test_millimetre_cloud_is_converted(lisa, files, capsys):
    root, points = files
    np.save(root / "scan_mm.npy", 1000.0 * points)
    out = root / "out_mm"
    assert lisa(["fit-points", str(root / "scan_mm.npy"), "--out", str(out), "--model",
                 str(root / "tiny.pt"), *FAST_ARGS]) == 0
    printed = capsys.readouterr().out
    assert "read as millimetres" in printed
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "params.json",
                                                     "preview.png"]
    translation = read_params(out / "params.json").translation.numpy()
    assert np.linalg.norm(translation - points.mean(0)) < 0.1  # metres, not millimetres


def test_side_left_fits_a_left_hand(lisa, files, capsys):
    root, points = files
    left = points * np.array([-1.0, 1.0, 1.0], dtype=points.dtype)  # the mirror image
    np.save(root / "left.npy", left)
    out = root / "out_left"
    assert lisa(["fit-points", str(root / "left.npy"), "--out", str(out), "--model",
                 str(root / "tiny.pt"), *FAST_ARGS, "--side", "left"]) == 0
    assert "fitted" in capsys.readouterr().out
    params = read_params(out / "params.json")
    assert params.side == "left"
    # The mesh of the left hand lies on the left cloud (mirrored by the mesher).
    vertices = load_mesh(out / "mesh.ply").vertices
    assert np.linalg.norm(vertices.mean(0) - left.mean(0)) < 0.02
    assert lisa(["fit-points", str(root / "left.npy"), "--out", str(root / "bad_side"),
                 *FAST_ARGS, "--side", "middle"]) == 2
    assert not (root / "bad_side").exists()


def test_side_auto_fits_both_and_says_which_it_kept(lisa, files, capsys):
    root, _ = files
    out = root / "out_auto"
    assert lisa(["fit-points", str(root / "scan.npz"), "--out", str(out), "--model",
                 str(root / "tiny.pt"), *FAST_ARGS, "--side", "auto"]) == 0
    printed = capsys.readouterr().out
    params = read_params(out / "params.json")
    distances = params.extra["fit"]["side_distances_mm"]
    other = "left" if params.side == "right" else "right"
    assert distances[params.side] <= distances[other]
    assert (f"fitted as a right and as a left hand; kept the {params.side} hand, "
            f"{distances[params.side]:.2f} mm from the scan against {distances[other]:.2f} mm"
            in printed)
    one_sided = params.extra["fit"]["coverage"] < 2.0 / 3.0
    close = distances[other] < 1.15 * distances[params.side]
    assert ("the scan shows one side of the hand" in printed) == one_sided
    assert ("(close: pass --side" in printed) == (close and not one_sided)


def test_the_side_choice_asks_for_side_when_it_cannot_be_trusted():
    from types import SimpleNamespace

    from lisa_hand.fitting.points.config import FitPointsConfig
    from lisa_hand.fitting.points.io import _side_choice
    from lisa_hand.skeleton.params import HandParams

    def fit(side, right, left, coverage):
        params = HandParams(pose=np.zeros(48), translation=np.zeros(3),
                            rest_joints=np.zeros((16, 3)), shape_code=np.zeros(8), side=side)
        return SimpleNamespace(params=params, side_distances_mm={"right": right, "left": left},
                               coverage=coverage)

    config = FitPointsConfig()
    clear = _side_choice("scan.ply", fit("left", 1.6, 1.0, 0.95), config)
    assert clear == ("scan.ply: fitted as a right and as a left hand; kept the left hand, "
                     "1.00 mm from the scan against 1.60 mm")
    close = _side_choice("scan.ply", fit("right", 1.1, 1.2, 0.95), config)
    assert close.endswith("(close: pass --side if you know which hand it is)")
    one_sided = _side_choice("scan.ply", fit("right", 1.0, 1.6, 0.45), config)
    assert "the scan shows one side of the hand, 45%" in one_sided and "close" not in one_sided


def test_bad_inputs_give_one_line_errors(lisa, files, capsys):
    root, points = files
    np.save(root / "empty.npy", np.zeros((0, 3)))
    np.save(root / "nan.npy", np.full((50, 3), np.nan))
    np.save(root / "mm.npy", 1000.0 * points)
    (root / "corrupt.pt").write_bytes(b"\x00garbage" * 100)
    cases = [
        (["empty.npy"], "empty.npy: the point cloud is empty"),
        (["nan.npy"], "nan.npy: only 0 of 50 points have finite coordinates"),
        (["mm.npy", "--units", "m"], "mm.npy: the cloud is"),
        (["missing.xyz"], "missing.xyz: no such file"),
        (["scan.npz", "--model", "corrupt.pt"], "corrupt.pt: not a LISA model file"),
        (["scan.npz", "--model", "nothing.pt"], "nothing.pt: no such model file"),
        (["scan.npz", "--gt", "nothing.ply"], "nothing.ply: no such file"),
    ]
    for arguments, message in cases:
        out = root / "failed"
        argv = ["fit-points", str(root / arguments[0]), "--out", str(out), *FAST_ARGS]
        extra = [str(root / a) if a.endswith((".pt", ".ply")) else a for a in arguments[1:]]
        if "--model" not in arguments:
            extra += ["--model", str(root / "tiny.pt")]
        assert lisa(argv + extra) == 2
        error = capsys.readouterr().err.strip()
        assert error.startswith("lisa: error: ") and message in error, (arguments, error)
        assert "\n" not in error and "Traceback" not in error
        assert not out.exists()  # nothing half-written
    # A millimetre cloud with --units m names the problem and the fix.
    assert lisa(["fit-points", str(root / "mm.npy"), "--out", str(root / "failed"), "--units",
                 "m", "--model", str(root / "tiny.pt"), *FAST_ARGS]) == 2
    assert "looks like millimetres" in capsys.readouterr().err


def test_viewpoint_is_read_in_the_clouds_units_and_recorded(lisa, files, capsys):
    """``--viewpoint X,Y,Z`` (a one-view scan's sensor position, in the cloud's units): the fit
    runs with the free-space term and params.json records the position in metres; a malformed
    or impossible one is a one-line error, nothing written."""
    root, points = files
    sensor = points.mean(0) + np.array([0.0, 0.0, 0.4])
    np.save(root / "scan_mm.npy", 1000.0 * points)
    out = root / "viewed"
    given = ",".join(f"{1000.0 * v:.6f}" for v in sensor)
    assert lisa(["fit-points", str(root / "scan_mm.npy"), "--out", str(out), "--model",
                 str(root / "tiny.pt"), "--viewpoint", given, *FAST_ARGS]) == 0
    recorded = read_params(out / "params.json").extra["input"]["viewpoint_m"]
    assert np.allclose(recorded, sensor, atol=1e-6)
    for bad, message in (("1,2", "--viewpoint: expected three numbers"), ("al", "auto or none"),
                         ("a,b,c", "--viewpoint: expected three numbers"),
                         (",".join(f"{v:.6f}" for v in points.mean(0)), "viewpoint: the scan")):
        failed = root / "failed_view"
        assert lisa(["fit-points", str(root / "scan.npz"), "--out", str(failed), "--model",
                     str(root / "tiny.pt"), "--viewpoint", bad, *FAST_ARGS]) == 2
        error = capsys.readouterr().err.strip()
        assert error.startswith("lisa: error: ") and message in error, (bad, error)
        assert "\n" not in error and not failed.exists()


def test_a_one_sided_scans_sensor_is_found_or_hinted_at(lisa, files, capsys):
    """A one-view scan (a toy model: it covers little of the fitted hand): by default
    (``--viewpoint auto``) its sensor is found from the points, said in one line and recorded
    (within 25 degrees of the true direction); with ``--viewpoint none`` it is fitted as it is,
    with one line on --viewpoint; given the sensor position, neither. params.json records the
    coverage."""
    root, _ = files
    with cpu_threads(1):
        model = tiny_model(color=True)
        truth = true_hand(model, seed=2)
        sensor = np.array([0.0, 0.0, 0.5])
        points, normals, _ = scan_of(model, truth, ScanConfig(
            num_points=4500, partial=True, viewpoint=tuple(sensor)), seed=2)
    np.savez(root / "one_view.npz", points=points, normals=normals)
    for name, extra in (("hinted", ["--viewpoint", "none"]), ("given", ["--viewpoint", "0,0,0.5"]),
                        ("found", [])):
        out = root / name
        assert lisa(["fit-points", str(root / "one_view.npz"), "--out", str(out), "--model",
                     str(root / "tiny.pt"), *extra, *FAST_ARGS]) == 0
        captured = capsys.readouterr()
        said = captured.out + captured.err
        params = read_params(out / "params.json")
        coverage = params.extra["fit"]["coverage"]
        assert 0.0 <= coverage < 2.0 / 3.0, coverage
        hinted = "--viewpoint X,Y,Z (the sensor" in said
        assert hinted == (name == "hinted"), said
        if hinted:
            assert f"shows {coverage:.0%} of the hand" in said
            assert "viewpoint_m" not in params.extra["input"]
            continue
        recorded = params.extra["input"]
        assert recorded["viewpoint_source"] == ("given" if name == "given" else "estimated")
        assert ("looks like one view" in said) == (name == "found"), said
        direction = np.asarray(recorded["viewpoint_m"]) - points.mean(0)
        cosine = direction @ (sensor - points.mean(0)) / (
            np.linalg.norm(direction) * np.linalg.norm(sensor - points.mean(0)))
        assert cosine > np.cos(np.radians(25.0)), (name, cosine)


def test_refine_writes_the_refined_model_that_params_json_names(lisa, files, capsys):
    """``--refine``: the per-bone SDF MLPs fine-tuned on the scan (a tiny model: few steps) and
    written as OUT/model.pt; params.json names it, so the verbs over a hand load it; the
    surface is nearer the scan than the unrefined fit's; only the SDF networks changed."""
    import torch

    from lisa_hand.inference.hand_field import load_hand
    from lisa_hand.model.trained import load_trained

    root, points = files
    out = root / "refined"
    assert lisa(["fit-points", str(root / "scan.npz"), "--out", str(out), "--model",
                 str(root / "tiny.pt"), *FAST_ARGS, "--refine", "--refine-iters", "40"]) == 0
    printed = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "model.pt",
                                                     "params.json", "preview.png"]
    params = read_params(out / "params.json")
    assert params.model == str((out / "model.pt").resolve())
    record = params.extra["refine"]
    assert record["mean_abs_sdf_after_mm"] < record["mean_abs_sdf_before_mm"]
    assert "refined the surface" in printed
    model, hand = load_hand(out / "params.json")
    original = load_trained(root / "tiny.pt")
    changed = {name for name, value in model.field.state_dict().items()
               if not torch.equal(value, original.field.state_dict()[name])}
    assert changed and all(name.startswith("sdf_mlp.") for name in changed)
    # The verbs over a hand use it: lisa mesh of the refined hand.
    assert lisa(["mesh", str(out / "params.json"), "--res", "32", "--out",
                 str(root / "refined_mesh.ply")]) == 0
    assert (root / "refined_mesh.ply").is_file()


def test_without_model_the_shipped_geometric_prior_fits(lisa, files, tmp_path, capsys):
    """No --model: the point fit uses the shipped geometric prior of hand models v1-v3
    ('geometry_v3'), and says so; params.json names it, the
    mesh has skinning weights and no colours (the prior has none), and the verbs over a hand
    load it by that name."""
    from lisa_hand.inference.hand_field import load_hand

    root, _ = files
    out = tmp_path / "fit"
    assert lisa(["fit-points", str(root / "scan.npz"), "--out", str(out), *FAST_ARGS]) == 0
    assert ("model: geometry_v3 (the point fit's default; --model to choose another)"
            in capsys.readouterr().out)
    params = read_params(out / "params.json")
    assert params.model == "geometry_v3" and params.color_code is None
    assert params.shape_code is not None and params.shape_code.shape == (128,)
    mesh = load_mesh(out / "mesh.ply")
    assert mesh.num_vertices > 100 and mesh.colors is None and mesh.skin_weights is not None
    model, hand = load_hand(out / "params.json")
    assert not model.has_color and model.source.endswith("lisa_geometry_v3.pt")
    assert hand.model == "geometry_v3"


def test_a_failed_preview_leaves_the_fit_written(lisa, files, capsys, monkeypatch):
    """``preview.png`` is a picture, not the fit: when drawing it fails, the command says so in
    one line and writes the fit's other files."""
    from lisa_hand.fitting.points import preview

    def broken(*args, **kwargs):
        raise RuntimeError("no rays today")

    monkeypatch.setattr(preview, "fit_preview", broken)
    root, _ = files
    out = root / "no_preview"
    assert lisa(["fit-points", str(root / "scan.npz"), "--out", str(out), "--model",
                 str(root / "tiny.pt"), *FAST_ARGS]) == 0
    said = capsys.readouterr().out
    assert "preview.png not written: RuntimeError: no rays today" in said
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "params.json"]


def _fitted(lisa, capsys, root, cloud: str, out: str, extra: list[str]) -> tuple[str, dict]:
    """``lisa fit-points ROOT/CLOUD --out ROOT/OUT`` with the tiny model and ``extra``, which
    must succeed -> (what it said, ``params.json``'s "fit")."""
    assert lisa(["fit-points", str(root / cloud), "--out", str(root / out), "--model",
                 str(root / "tiny.pt"), *extra, *FAST_ARGS]) == 0
    captured = capsys.readouterr()
    return captured.out + captured.err, read_params(root / out / "params.json").extra["fit"]


def test_a_surface_the_hand_rests_on_is_left_out_and_said(lisa, files, capsys):
    """A one-view scan of the hand in front of a wall: by default (``--support auto``) the
    wall's points are left out, one line says so, params.json records the plane and the preview
    greys them; ``--support none`` fits every point."""
    from tests.fitting.test_support import with_wall

    root, _ = files
    with cpu_threads(1):
        model = tiny_model(color=True)
        mesh = surface(model, true_hand(model, seed=2))
    vertices, faces, wall, _ = with_wall(np.asarray(mesh.vertices, np.float64),
                                         np.asarray(mesh.faces), side=0.25)
    sensor = np.asarray(mesh.vertices).mean(0) - np.array([0.0, 0.0, 0.4])
    from lisa_hand.data.scans import simulate_scan

    scan = simulate_scan(vertices, faces, ScanConfig(num_points=3000, partial=True,
                                                     viewpoint=tuple(sensor)), seed=0)
    np.save(root / "walled.npy", scan.points)
    for name, extra in (("kept", ["--support", "none"]), ("left", [])):
        said, fit = _fitted(lisa, capsys, root, "walled.npy", f"wall_{name}", extra)
        assert ("a surface the hand rests on" in said) == (name == "left"), said
        assert ("support_plane" in fit) == (name == "left")
        if name == "left":
            plane = fit["support_plane"]
            assert np.asarray(plane["normal"]) @ wall.normal > np.cos(np.radians(2.0))
            assert f"{plane['removed_points']} of 3000 points lie on" in said
            assert fit["num_points"] + fit["beyond_wrist_points"] == 3000 - plane[
                "removed_points"]
    assert lisa(["fit-points", str(root / "walled.npy"), "--out", str(root / "bad"),
                 "--model", str(root / "tiny.pt"), "--support", "maybe", *FAST_ARGS]) != 0
    assert "--support: expected auto or none" in capsys.readouterr().err


def test_a_thing_apart_from_the_hand_is_left_out_and_said(lisa, files, capsys):
    """A scan with a ball 25 cm from the hand (half as many points): by default (``--others
    auto``) its points are left out, one line says so and params.json records it; ``--others
    none`` keeps them. A ball as large as the hand is kept, and the command says why."""
    from tests.fitting.test_others import ball

    root, points = files
    thing = ball(points.mean(0) + np.array([0.25, 0.0, 0.0]), 0.04, len(points) // 2, seed=0)
    np.save(root / "with_ball.npy", np.concatenate([points, thing]))
    for name, extra in (("kept", ["--others", "none"]), ("left", [])):
        said, fit = _fitted(lisa, capsys, root, "with_ball.npy", f"ball_{name}", extra)
        assert (f"{len(thing)} points in 1 piece(s)" in said) == (name == "left"), said
        assert ("others" in fit) == (name == "left")
    # A thing as large as the hand (as many points, 25 cm away) may be a second hand: each is
    # fitted on its own, into OUT/hand0 and OUT/hand1, without the other's points.
    large = ball(points.mean(0) + np.array([0.25, 0.0, 0.0]), 0.04, len(points), seed=0)
    np.save(root / "with_large_ball.npy", np.concatenate([points, large]))
    assert lisa(["fit-points", str(root / "with_large_ball.npy"), "--out", str(root / "large"),
                 "--model", str(root / "tiny.pt"), *FAST_ARGS]) == 0
    captured = capsys.readouterr()
    assert "2 hands apart from each other: fitting each into" in captured.out + captured.err
    for index in (0, 1):
        record = read_params(root / "large" / f"hand{index}" / "params.json").extra
        note = next(n for n in record["input"]["notes"] if n.startswith(f"hand {index} of 2"))
        left_out = int(note.split("the other hands' ")[1].split(" points")[0])
        assert 0.9 * len(points) <= left_out <= len(points)  # the other piece (a few strays
        # of the hand's scan, pieces of their own, stay with the ball)
        assert "others" not in record["fit"]  # the other piece was never in this fit
    assert lisa(["fit-points", str(root / "with_large_ball.npy"), "--out", str(root / "one"),
                 "--hand", "1", "--model", str(root / "tiny.pt"), *FAST_ARGS]) == 0
    assert (root / "one" / "params.json").is_file() and not (root / "one" / "hand0").exists()
    capsys.readouterr()
    for extra, message in ((["--hand", "2"], "--hand 2 asked for, but the scan holds 2 hand"),
                           (["--gt", str(root / "truth.ply")], "--gt compares one: pass --hand")):
        assert lisa(["fit-points", str(root / "with_large_ball.npy"), "--out",
                     str(root / "bad"), "--model", str(root / "tiny.pt"), *extra,
                     *FAST_ARGS]) == 2
        assert message in capsys.readouterr().err


def _depth_camera_files(root):
    """root/depth.png (16-bit millimetres, 80 x 60), root/mask.png and root/cam.json of a camera
    40 cm before the test hand (R = I) -> (depth [60, 80] metres, sensor [3] metres)."""
    import imageio.v3 as iio

    from lisa_hand.render.raycast import MeshRayCaster

    truth = load_mesh(root / "truth.ply")
    centre = np.asarray(truth.vertices, np.float64).mean(0)
    sensor = centre - np.array([0.0, 0.0, 0.4])  # R = I, t = -sensor: the camera 40 cm away
    width, height, focal = 80, 60, 150.0
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    rays = np.stack([(u - width / 2) / focal, (v - height / 2) / focal, np.ones_like(u)],
                    -1).reshape(-1, 3)
    unit = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    hits = MeshRayCaster(truth.vertices, truth.faces).intersect(
        np.tile(sensor, (len(unit), 1)), unit)
    depth = np.where(hits.hit, hits.distances * unit[:, 2], 0.0).reshape(height, width)
    iio.imwrite(root / "depth.png", np.round(depth * 1000).astype(np.uint16))
    iio.imwrite(root / "mask.png", ((depth > 0) * 255).astype(np.uint8))
    (root / "cam.json").write_text(json.dumps([{
        "K": [[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1]],
        "R": np.eye(3).tolist(), "t": (-sensor).tolist(), "width": width, "height": height}]))
    return depth, sensor


def test_a_depth_image_is_fitted_with_its_camera(lisa, files, capsys):
    """A 16-bit depth image (millimetres) of the hand with its camera (cameras.json): its
    pixels are the points, the camera's centre the sensor; without --camera, one line says what
    to pass; --mask keeps the hand's pixels."""
    import imageio.v3 as iio

    root, _ = files
    depth, sensor = _depth_camera_files(root)
    pixels = int((depth > 0).sum())
    assert pixels > 200
    for name, extra in (("whole", []), ("masked", ["--mask", str(root / "mask.png")])):
        assert lisa(["fit-points", str(root / "depth.png"), "--out", str(root / name),
                     "--camera", str(root / "cam.json"), "--model", str(root / "tiny.pt"),
                     *extra, *FAST_ARGS]) == 0
        said = capsys.readouterr().out
        assert f"read {pixels} pixels with a depth" in said
        record = read_params(root / name / "params.json").extra["input"]
        assert np.allclose(record["viewpoint_m"], sensor, atol=1e-6)
    assert lisa(["fit-points", str(root / "depth.png"), "--out", str(root / "bad"),
                 "--model", str(root / "tiny.pt"), *FAST_ARGS]) == 2
    assert "pass --camera CAM.json" in capsys.readouterr().err
    room = np.where(depth > 0, depth, 3.0)  # a room 3 m behind the hand: over 2 m across
    iio.imwrite(root / "room.png", np.round(room * 1000).astype(np.uint16))
    assert lisa(["fit-points", str(root / "room.png"), "--out", str(root / "bad"), "--camera",
                 str(root / "cam.json"), "--model", str(root / "tiny.pt"), *FAST_ARGS]) == 2
    assert "(the room behind the hand): pass --mask" in capsys.readouterr().err
    assert lisa(["fit-points", str(root / "scan.npz"), "--out", str(root / "bad"), "--camera",
                 str(root / "cam.json"), "--model", str(root / "tiny.pt"), *FAST_ARGS]) == 2
    assert "are for a depth image" in capsys.readouterr().err


def test_a_hand_before_a_body_is_taken_nearest_the_sensor(lisa, files, capsys):
    """A scan of the hand held out before a person (an arm into a round body, one piece over a
    metre across) with its sensor known (--viewpoint): the part nearest the sensor is fitted,
    and one line says so; without the sensor, one line says to crop."""
    from lisa_hand.data.scans import simulate_scan
    from tests.fitting.test_others import ball, rod

    root, _ = files
    truth = load_mesh(root / "truth.ply")
    sensor = np.asarray(truth.vertices, np.float64).mean(0) - np.array([0.0, 0.0, 0.4])
    points = simulate_scan(truth.vertices, truth.faces, ScanConfig(
        num_points=1500, partial=True, viewpoint=tuple(sensor)), seed=3).points
    back = points[np.argmax(points[:, 2])]
    body = ball(back + [0.0, 0.0, 0.6], 0.3, 30000, seed=6)
    body = body[body[:, 2] < back[2] + 0.6]
    cloud = np.concatenate([points, rod(back, back + [0.0, 0.0, 0.3], 0.004), body])
    np.save(root / "person.npy", cloud)
    view = ",".join(f"{v:.6f}" for v in sensor)
    assert lisa(["fit-points", str(root / "person.npy"), "--out", str(root / "person"),
                 "--model", str(root / "tiny.pt"), "--viewpoint", view, *FAST_ARGS]) == 0
    said = capsys.readouterr().out
    others = read_params(root / "person" / "params.json").extra["fit"]["others"]
    kept = len(cloud) - others["removed_points"]
    assert len(points) <= kept < len(points) + 150  # the hand and a stub of the arm
    assert (f"the hand was taken to be what is nearest the sensor "
            f"({others['nearest_m']:.2f} m away), {kept} of {len(cloud)} points") in said
    assert lisa(["fit-points", str(root / "person.npy"), "--out", str(root / "blind"),
                 "--model", str(root / "tiny.pt"), "--viewpoint", "none", *FAST_ARGS]) == 0
    assert "larger than a hand (a wall, a person): nothing was left out" in \
        capsys.readouterr().out


def test_the_hand_in_the_colour_image_says_which_pixels(lisa, files, capsys, monkeypatch):
    """--rgb: the hand found in the colour image beside the depth image (a stand-in detector
    here: a skeleton over the hand's pixels, called a left hand) keeps its pixels out of a room
    3 m behind it and gives its side to --side auto; with --mask or without --camera, one line."""
    import imageio.v3 as iio

    from lisa_hand.fitting.points import rgbd
    from tests.fitting.test_rgbd import Found, hand_keypoints

    root, _ = files
    depth, _ = _depth_camera_files(root)
    room = np.where(depth > 0, depth, 3.0)
    iio.imwrite(root / "room.png", np.round(room * 1000).astype(np.uint16))
    iio.imwrite(root / "colour.png", np.full((60, 80, 3), 90, np.uint8))
    rows, cols = np.nonzero(depth > 0)
    size = 0.45 * (rows.max() - rows.min())  # wrist at the bottom, fingertips near the top
    hand = Found(hand_keypoints(cols.mean(), rows.max(), size), "left")
    monkeypatch.setattr(rgbd, "detect_hands", lambda image: [hand])
    monkeypatch.setattr(rgbd, "photo_extra_missing", lambda: None)
    base = ["fit-points", str(root / "room.png"), "--camera", str(root / "cam.json"), "--model",
            str(root / "tiny.pt"), "--rgb", str(root / "colour.png"), *FAST_ARGS, "--side", "auto"]
    assert lisa([*base, "--out", str(root / "rgbd")]) == 0
    said = capsys.readouterr().out
    kept = rgbd.find_colour_hand(root / "colour.png", (80, 60), detect=lambda image: [hand]).mask
    assert f"found a left hand in the colour image {root / 'colour.png'}" in said
    kept &= room < 1.0  # the room 3 m behind, taken in by the mask's margin, dropped by depth
    assert f"read {int(kept.sum())} pixels with a depth inside the hand's mask" in said
    assert (kept & (depth > 0)).sum() > 0.8 * (depth > 0).sum()  # most of the hand (a stand-in)
    assert read_params(root / "rgbd" / "params.json").side == "left"
    colours = load_mesh(root / "rgbd" / "mesh.ply").colors  # the colour image's grey where seen
    seen = read_params(root / "rgbd" / "params.json").extra["input"]["colours"]["seen_share"]
    assert seen > 0.2 and np.all(colours == 90, axis=1).mean() >= seen - 1e-3
    assert lisa([*base, "--out", str(root / "bad"), "--mask", str(root / "mask.png")]) == 2
    assert "a colour image and a mask both say" in capsys.readouterr().err
    assert lisa(["fit-points", str(root / "room.png"), "--out", str(root / "bad"), "--rgb",
                 str(root / "colour.png"), *FAST_ARGS]) == 2
    assert "--rgb read a depth image with its camera: pass --camera" in capsys.readouterr().err


def test_a_coloured_scan_colours_the_mesh(lisa, files, capsys):
    """A PLY scan whose points carry colours (red along x, green along y): mesh.ply's vertices
    near the scan take them, the command says how much of the surface it saw, params.json
    records it; --colours none leaves the model's own colours."""
    import trimesh

    root, points = files
    low, high = points.min(0), points.max(0)

    def paint(at):
        return np.stack([(at[:, 0] - low[0]) / (high[0] - low[0]),
                         (at[:, 1] - low[1]) / (high[1] - low[1]), np.full(len(at), 0.5)], 1)

    colours = np.round(255 * paint(points)).astype(np.uint8)
    trimesh.PointCloud(points, colors=colours).export(root / "coloured.ply")
    out = root / "coloured"
    assert lisa(["fit-points", str(root / "coloured.ply"), "--out", str(out), "--model",
                 str(root / "tiny.pt"), *FAST_ARGS]) == 0
    said = capsys.readouterr().out
    record = read_params(out / "params.json").extra["input"]["colours"]
    assert record["used"] and 0.3 < record["seen_share"] <= 1.0
    assert record["colour_code_fitted"]  # a colour model: its code fitted to the scan's
    assert f"coloured from the scan's colours ({100 * record['seen_share']:.0f}% of" in said
    mesh = load_mesh(out / "mesh.ply")
    near = np.linalg.norm(mesh.vertices[:, None] - points[None], axis=-1).min(1) < 0.002
    error = np.abs(mesh.colors[near] / 255.0 - paint(mesh.vertices[near]))
    assert near.sum() > 50 and np.median(error) < 0.05
    assert lisa(["fit-points", str(root / "coloured.ply"), "--out", str(root / "plain"),
                 "--model", str(root / "tiny.pt"), "--colours", "none", *FAST_ARGS]) == 0
    assert "coloured from the scan" not in capsys.readouterr().out
    assert "colours" not in read_params(root / "plain" / "params.json").extra["input"]
    assert not np.array_equal(load_mesh(root / "plain" / "mesh.ply").colors, mesh.colors)
    # Colours that cannot be read are an extra lost, not a failed fit: one line says so.
    np.savez(root / "odd.npz", points=points, colors=np.full((len(points), 3), 999.0))
    assert lisa(["fit-points", str(root / "odd.npz"), "--out", str(root / "odd"), "--model",
                 str(root / "tiny.pt"), *FAST_ARGS]) == 0
    assert (f"{root / 'odd.npz'}: its colours were not read (colours reach 999: expected [0, 1] "
            "or [0, 255]); the points are fitted without them") in capsys.readouterr().out
