"""The public API of ``import lisa_hand``: every name resolves and is documented, the import
stays light (nothing of torch or the fitters until a name is used), and the examples of
``docs/api.md`` run as written and give real numbers (a fitted surface within a few mm of the
true one, shapes of meshes and images)."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import lisa_hand
from lisa_hand.utils.threads import cpu_threads

DOCS = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def python_blocks(markdown: str) -> list[str]:
    """The ```python blocks of a Markdown page, in order."""
    return re.findall(r"^```python\n(.*?)^```$", markdown, flags=re.S | re.M)


def modules_after(code: str) -> set[str]:
    """The modules loaded by a fresh interpreter after running ``code``."""
    script = f"import json, sys\n{code}\nprint(json.dumps(sorted(sys.modules)))"
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            check=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    return set(json.loads(result.stdout.splitlines()[-1]))


def posed_joints(params) -> torch.Tensor:
    """[16, 3] the posed joints of a hand, metres."""
    from lisa_hand.skeleton import forward_kinematics

    return forward_kinematics(params.pose[None], params.rest_joints[None],
                              params.translation[None]).joints[0]


# ---------------------------------------------------------------------------------------------
# The names


def test_every_exported_name_resolves_and_is_documented():
    assert lisa_hand.__all__[0] == "__version__" and isinstance(lisa_hand.__version__, str)
    assert len(set(lisa_hand.__all__)) == len(lisa_hand.__all__)
    for name in lisa_hand.__all__[1:]:
        value = getattr(lisa_hand, name)
        doc = value.__doc__ or ""
        assert doc.strip(), f"lisa_hand.{name} has no docstring"
        if getattr(value, "__module__", None) == "lisa_hand":  # the API's own functions
            assert "->" in doc, f"lisa_hand.{name}: its docstring does not say what it returns"
            assert "metres" in doc or "[N" in doc, f"lisa_hand.{name}: no shapes or units"
    assert set(lisa_hand.__all__) <= set(dir(lisa_hand))


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'fit_everything'"):
        lisa_hand.fit_everything  # noqa: B018


def test_import_is_light():
    loaded = modules_after("import lisa_hand")
    assert "lisa_hand.fitting" not in loaded
    heavy = {"torch", "numpy", "mediapipe", "viser", "typer"} & loaded
    assert not heavy, f"import lisa_hand loaded {sorted(heavy)}"
    assert {name for name in loaded if name.startswith("lisa_hand")} == {"lisa_hand"}


def test_a_name_imports_only_what_it_needs():
    loaded = modules_after("import lisa_hand\nlisa_hand.HandParams\nlisa_hand.load_model")
    assert "lisa_hand.skeleton.params" in loaded
    for absent in ("lisa_hand.fitting", "lisa_hand.inference", "mediapipe", "viser"):
        assert absent not in loaded, f"{absent} was imported"


def test_settings_are_checked_by_name():
    with pytest.raises(TypeError, match="unknown FitPointsConfig setting.*field_itters"):
        lisa_hand.fit_points(np.zeros((100, 3)), field_itters=3)


def test_evaluate_hand_checks_the_points():
    model = lisa_hand.load_model("geometry", device="cpu")
    with pytest.raises(ValueError, match=r"points must have shape \[N, 3\]"):
        lisa_hand.evaluate_hand(np.zeros((4, 2)), model=model)


def test_evaluate_hand_of_a_left_hand_mirrors_the_right_one():
    model = lisa_hand.load_model("geometry", device="cpu")
    points = np.random.default_rng(1).uniform(-0.1, 0.1, size=(300, 3))
    right = lisa_hand.evaluate_hand(points, model=model)
    left = lisa_hand.evaluate_hand(points * np.array([-1.0, 1.0, 1.0]), model=model,
                                   side="left")
    torch.testing.assert_close(left.sdf, right.sdf, atol=1e-6, rtol=0)
    assert right.rgb.shape == (300, 3) and torch.all(right.rgb == right.rgb[0])  # grey prior


def test_fit_points_reads_a_file_in_its_units(tmp_path, one_thread):
    from lisa_hand.data.scans import ScanConfig
    from tests.fitting.test_points import FAST, scan_of, tiny_model, true_hand

    model = tiny_model()
    truth = true_hand(model, seed=0)
    points, _, _ = scan_of(model, truth, ScanConfig(num_points=600), seed=0)
    path = tmp_path / "scan_mm.xyz"
    np.savetxt(path, 1000.0 * points)  # millimetres
    fit = lisa_hand.fit_points(path, model=model, side="right", viewpoint=None, **FAST)
    assert fit.params.extra["input"] == {"path": str(path), "unit": "mm",
                                         "num_input_points": len(points),
                                         "notes": fit.params.extra["input"]["notes"]}
    assert fit.params.model == "test"  # the loaded model's source
    assert fit.residual_median_mm < 2.0
    assert float((fit.params.translation - truth.translation).norm()) < 0.02  # metres


# ---------------------------------------------------------------------------------------------
# The examples of docs/api.md, run as written


@pytest.fixture(scope="module")
def examples(tmp_path_factory):
    """The namespace after running every ```python block of docs/api.md in order (in an empty
    folder, torch on one thread), and the seconds it took."""
    import time

    blocks = python_blocks(DOCS.read_text())
    assert len(blocks) >= 6
    namespace: dict = {"__name__": "docs_api"}
    folder, before = tmp_path_factory.mktemp("api_examples"), Path.cwd()
    start = time.perf_counter()
    os.chdir(folder)
    try:
        with cpu_threads(1):
            for index, block in enumerate(blocks):
                exec(compile(block, f"{DOCS}:block{index}", "exec"), namespace)
    finally:
        os.chdir(before)
    namespace["_seconds"] = time.perf_counter() - start
    return namespace


@pytest.mark.slow
def test_the_examples_run_quickly(examples):
    assert examples["_seconds"] < 120.0  # about 30 s on one thread of the 2-core CI machine


@pytest.mark.slow
def test_example_model_as_a_function(examples):
    rest, fist, points = examples["rest"], examples["fist"], examples["points"]
    assert rest.sdf.shape == (len(points),) and rest.weights.shape == (len(points), 16)
    assert rest.rgb.shape == (len(points), 3)
    assert float(rest.rgb.min()) >= 0.0 and float(rest.rgb.max()) <= 1.0
    torch.testing.assert_close(rest.weights.sum(dim=1), torch.ones(len(points)))
    assert 0 < int((rest.sdf < 0).sum()) < len(points) // 2  # a hand among the points
    assert not torch.allclose(rest.sdf, fist.sdf)  # the pose moves the surface
    assert not torch.allclose(rest.rgb, fist.rgb)  # and another colour code colours it


@pytest.mark.slow
def test_example_point_fit_is_near_the_true_surface(examples):
    fit, error = examples["fit"], examples["error"]
    assert fit.params.model == "geometry_v3"  # the command's default
    assert fit.residual_median_mm < 1.5
    assert error.v2s_recon_to_scan_mm < 1.0, error  # fitted surface -> true one, mm (0.25)
    assert error.v2s_scan_to_recon_mm < 1.0, error  # and back (0.28)
    true_joints = examples["true_hand"].joints.float()
    assert float((posed_joints(fit.params) - true_joints).norm(dim=-1).mean()) < 0.005  # m


@pytest.mark.slow
def test_example_mesh_and_images(examples):
    mesh = examples["mesh"]
    assert mesh.vertices.shape[1] == 3 and len(mesh.faces) > 1000
    assert mesh.skin_weights.shape == (len(mesh.vertices), 16)
    assert mesh.colors.shape == (len(mesh.vertices), 3) and mesh.colors.dtype == np.uint8
    extent = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
    assert 0.08 < float(extent.max()) < 0.3  # metres: a hand
    images = examples["images"]
    assert len(images) == 2 and images[0].rgb.shape == (96, 96, 3)
    coverage = float(images[0].mask.float().mean())
    assert 0.05 < coverage < 0.8
    assert examples["hand"].model == "geometry_v3"
    assert math.isclose(len(examples["mesh_again"].vertices), len(mesh.vertices), rel_tol=0.7)


@pytest.mark.slow
def test_example_image_and_photo_fits(examples):
    image_fit = examples["image_fit"]
    assert image_fit.keypoint_error_px["keypoints"] < 1.0
    true_joints = examples["posed"].joints.float()
    assert float((posed_joints(image_fit.params) - true_joints).norm(dim=-1).mean()) < 0.005
    report = examples["reports"][0]
    assert report.keypoint_error_px[0] < 1.0
    assert {"params.json", "mesh.ply", "overlay.png"} <= {path.name for path in report.written}
