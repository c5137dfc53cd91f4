"""``--set KEY=VALUE`` of ``lisa fit-images``, ``lisa fit-photo`` and ``lisa fit-points``: any
field of the fit's config, applied after the command's own options and recorded in the written
``params.json`` (``extra.config``); a bad key or value is one line and exit status 2, a renamed
key names its new name."""

from __future__ import annotations

import pytest

from lisa_hand.cli import fit_points as fit_points_cli
from lisa_hand.cli import main
from lisa_hand.fitting.images.config import FitImagesConfig
from lisa_hand.fitting.photo.config import FitPhotoConfig
from lisa_hand.model.trained import export_trained
from lisa_hand.skeleton.params import read_params
from lisa_hand.utils.config import apply_overrides, config_from_dict
from tests.fitting.image_scene import render_frame, tiny_model, true_hand, write_frame
from tests.fitting.photo.photo_scene import (
    FOCAL,
    photo_hand,
    render_photo,
    save_jpeg,
    save_keypoints,
)

QUICK = ["--rays", "64", "--res", "32", "--device", "cpu", "--no-progress"]


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


def run(argv, capsys) -> tuple[int, str, str]:
    try:
        main.main(argv)
        code = 0
    except SystemExit as exit_:
        code = exit_.code or 0
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fit_settings")
    model = tiny_model()
    model_path, _ = export_trained(model, folder / "model.pt")
    frame = write_frame(folder / "f000", render_frame(model, true_hand(model)))
    photo = render_photo(model, [photo_hand(model)])
    return {"model": model_path, "frame": frame,
            "jpeg": save_jpeg(folder / "hand.jpg", photo.image),
            "keypoints": save_keypoints(folder / "hand.keypoints.json", photo.keypoints[0],
                                        side="right")}


def test_fit_images_set_is_applied_after_the_options_and_written(files, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run(["fit-images", str(files["frame"]), "--out", str(out), "--model",
                        str(files["model"]), "--keypoint-iters", "60", "--color-iters", "0",
                        "--no-psnr", *QUICK, "--set", "keypoint_iters=20",
                        "--set", "code_lr=0.02", "--set", "render.num_samples=8"], capsys)
    assert code == 0, err
    written = read_params(out / "params.json").extra["config"]
    assert written["keypoint_iters"] == 20 and written["color_iters"] == 0  # --set wins
    assert written["code_lr"] == 0.02 and written["render"]["num_samples"] == 8
    assert written["num_rays"] == 64  # the command's own option
    expected = apply_overrides(FitImagesConfig(), {
        "keypoint_iters": 20, "color_iters": 0, "num_rays": 64, "code_lr": 0.02,
        "render.num_samples": 8})
    assert config_from_dict(FitImagesConfig, written) == expected


def test_fit_photo_set_reaches_the_image_fit_under_fit(files, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run(["fit-photo", str(files["jpeg"]), "--keypoints", str(files["keypoints"]),
                        "--focal-px", str(FOCAL), "--model", str(files["model"]), "--out",
                        str(out), "--keypoint-iters", "100", "--color-iters", "3", *QUICK,
                        "--set", "fit.keypoint_iters=30", "--set", "fit.color_iters=0",
                        "--set", "mesh_resolution=24"], capsys)
    assert code == 0, err
    written = read_params(out / "params.json").extra["config"]
    assert written["mesh_resolution"] == 24  # --set wins over --res
    assert written["fit"]["keypoint_iters"] == 30 and written["fit"]["color_iters"] == 0
    assert written["fit"]["num_rays"] == 64
    config = config_from_dict(FitPhotoConfig, written)
    assert config.fit.keypoint_iters == 30 and config.mesh_resolution == 24


def test_fit_points_set_is_applied_after_the_options(files, tmp_path, monkeypatch, capsys):
    seen = {}

    def fit_each(points, out, count, hand, **options):
        seen.update(options)

    monkeypatch.setattr(fit_points_cli, "_fit_each", fit_each)
    code, _, err = run(["fit-points", str(tmp_path / "scan.ply"), "--out", str(tmp_path / "o"),
                        "--hand", "0", "--field-iters", "15", "--restarts", "1", "--seed", "4",
                        "--refine", "--set", "field_iters=5", "--set", "seed=7",
                        "--set", "prior_pose=flat", "--set", "stages=align,pose,field",
                        "--set", "analysis.support.threshold_m=0.004"], capsys)
    assert code == 0, err
    config = seen["config"]
    assert (config.field_iters, config.seed, config.prior_pose) == (5, 7, "flat")
    assert config.stages == ("align", "pose", "field")
    assert config.analysis.support.threshold_m == 0.004
    assert config.restarts == 1  # the command's own option
    assert seen["refine"].seed == 7  # the refinement follows the fit's seed


@pytest.mark.parametrize("command, setting, message", [
    ("fit-images", "keypoint_iter=5",
     "unknown key 'keypoint_iter'; did you mean 'keypoint_iters'?"),
    ("fit-images", "latent_weight=0", "unknown key 'latent_weight': it was renamed 'code_weight'"),
    ("fit-images", "shape_prior_weight=0",
     "unknown key 'shape_prior_weight': it was renamed 'shape_weight'"),
    ("fit-images", "keypoint_iters=many", "keypoint_iters expects int, got 'many'"),
    ("fit-images", "shape_weight=-1", "shape_weight must be >= 0"),
    ("fit-photo", "keypoint_iters=5",
     "unknown key 'keypoint_iters'; did you mean 'fit.keypoint_iters'?"),
    ("fit-photo", "fit.latent_lr=0.1", "unknown key 'fit.latent_lr': it was renamed 'fit.code_lr'"),
    ("fit-photo", "max_sides=5", "unknown key 'max_sides'; did you mean 'max_side'?"),
    ("fit-points", "field_iter=5", "unknown key 'field_iter'; did you mean 'field_iters'?"),
    ("fit-points", "field_iters=-5", "field_iters must be an int >= 0"),
    ("fit-points", "lr_decay=0.2", "unknown key 'lr_decay': it was renamed 'final_lr_fraction'"),
    ("fit-points", "stages=field,align", "stages must name, in the order align"),
    ("fit-images", "stages=color", "stages must be one of"),
])
def test_a_bad_setting_is_one_line_and_exit_2(files, tmp_path, capsys, monkeypatch, command,
                                              setting, message):
    import lisa_hand.model.trained

    def refuse(*args, **kwargs):
        raise AssertionError("the model was loaded before the settings were checked")

    monkeypatch.setattr(lisa_hand.model.trained, "load_trained", refuse)
    inputs = {"fit-images": [str(files["frame"])],
              "fit-photo": [str(files["jpeg"]), "--keypoints", str(files["keypoints"])],
              "fit-points": [str(tmp_path / "scan.ply")]}[command]
    code, _, err = run([command, *inputs, "--out", str(tmp_path / "out"), "--set", setting],
                       capsys)
    assert code == 2, err
    assert err.startswith("lisa: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["fit-images", "fit-photo", "fit-points"])
def test_help_shows_set(command, capsys):
    code, text, _ = run([command, "--help"], capsys)
    assert code == 0 and "--set" in text and "KEY=VALUE" in text
