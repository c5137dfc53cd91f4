import json

import numpy as np
import pytest
import trimesh
import typer
from typer.testing import CliRunner

from lisa_hand.cli.metrics import register
from lisa_hand.data.layout import write_image, write_mask
from lisa_hand.metrics import lpips_unavailable_reason


@pytest.fixture()
def app() -> typer.Typer:
    app = typer.Typer()

    @app.callback()
    def _root() -> None:
        """Test app."""

    register(app)
    return app


@pytest.fixture()
def spheres(tmp_path):
    inner = trimesh.creation.icosphere(subdivisions=3, radius=0.050)
    outer = trimesh.creation.icosphere(subdivisions=3, radius=0.053)
    inner.export(tmp_path / "recon.ply")
    outer.export(tmp_path / "scan.ply")
    return tmp_path, inner, outer


def test_metrics_prints_table_and_writes_json(app, spheres):
    tmp_path, _, _ = spheres
    out = tmp_path / "out" / "metrics.json"
    result = CliRunner().invoke(
        app,
        ["metrics", str(tmp_path / "recon.ply"), str(tmp_path / "scan.ply"), "--json", str(out)],
    )
    assert result.exit_code == 0, result.output
    assert "V2S recon -> scan" in result.output and "millimetres" not in result.output
    values = json.loads(out.read_text())
    assert list(values) == ["v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm",
                            "v2v_scan_to_recon_mm", "v2s_scan_to_recon_mm"]
    # Same vertex directions: V2V is exactly the 3 mm radius gap; V2S within the sagitta
    # (edges ~8 mm on a 5 cm sphere -> sagitta < 0.25 mm); 1e-5 mm covers the float32 PLY.
    assert values["v2v_recon_to_scan_mm"] == pytest.approx(3.0, abs=1e-5)
    assert values["v2v_scan_to_recon_mm"] == pytest.approx(3.0, abs=1e-5)
    assert 2.75 < values["v2s_recon_to_scan_mm"] <= 3.0 + 1e-5
    assert 3.0 - 1e-5 <= values["v2s_scan_to_recon_mm"] < 3.25
    assert f"{values['v2v_recon_to_scan_mm']:.4f}" in result.output


def test_metrics_detects_millimetres_and_points(app, spheres):
    tmp_path, _, outer = spheres
    # The scan in millimetres and as points only.
    np.save(tmp_path / "scan_mm.npy", 1000.0 * outer.vertices)
    out = tmp_path / "metrics.json"
    result = CliRunner().invoke(
        app, ["metrics", str(tmp_path / "recon.ply"), str(tmp_path / "scan_mm.npy"),
              "--json", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert "scan_mm.npy: bounding box over 2 units across, read as millimetres" in result.output
    assert "n/a" in result.output and "has no faces" in result.output
    values = json.loads(out.read_text())
    assert values["v2s_recon_to_scan_mm"] is None
    assert values["v2v_recon_to_scan_mm"] == pytest.approx(3.0, abs=1e-5)
    # Forcing metres on the millimetre file: read as a 53 m sphere, as asked.
    forced = CliRunner().invoke(
        app, ["metrics", str(tmp_path / "recon.ply"), str(tmp_path / "scan_mm.npy"),
              "--units", "m", "--json", str(out)]
    )
    assert forced.exit_code == 0, forced.output
    assert "millimetres" not in forced.output
    assert json.loads(out.read_text())["v2v_recon_to_scan_mm"] == pytest.approx(52950.0, abs=1e-3)


def test_metrics_missing_file_is_an_error(app, tmp_path):
    result = CliRunner().invoke(app, ["metrics", str(tmp_path / "nope.ply"),
                                      str(tmp_path / "nope2.ply")])
    assert result.exit_code != 0
    assert isinstance(result.exception, FileNotFoundError)
    assert "nope.ply" in str(result.exception)


@pytest.fixture()
def images(tmp_path):
    rng = np.random.default_rng(0)
    target = rng.integers(0, 256, size=(32, 40, 3), dtype=np.uint8)
    mask = np.zeros((32, 40), dtype=bool)
    mask[8:24, 10:30] = True
    pred = target.astype(np.int64)
    pred[mask] += np.where(pred[mask] < 128, 10, -10)  # |error| = 10/255 inside the mask
    pred[~mask] = 255 - pred[~mask]  # large errors outside it
    write_image(tmp_path / "target.png", target)
    write_image(tmp_path / "pred.png", pred.astype(np.uint8))
    write_mask(tmp_path / "mask.png", mask)
    return tmp_path


def test_metrics_on_images_prints_psnr_ssim_and_lpips_or_one_line(app, images):
    out = images / "image_metrics.json"
    result = CliRunner().invoke(app, [
        "metrics", str(images / "pred.png"), str(images / "target.png"),
        "--mask", str(images / "mask.png"), "--json", str(out)])
    assert result.exit_code == 0, result.output
    values = json.loads(out.read_text())
    assert list(values) == ["psnr_db", "ssim", "psnr_mask_db", "ssim_mask", "lpips"]
    assert values["psnr_mask_db"] == pytest.approx(20.0 * np.log10(255.0 / 10.0), rel=1e-6)
    assert values["psnr_db"] < values["psnr_mask_db"] - 5.0
    assert f"{values['psnr_mask_db']:.4f}" in result.output and "SSIM in mask" in result.output
    reason = lpips_unavailable_reason()
    if reason:
        assert values["lpips"] is None
        lines = [line for line in result.output.splitlines() if "LPIPS unavailable" in line]
        assert lines == [reason]
    else:
        assert values["lpips"] > 0.0
    # Without a mask: no masked rows.
    plain = CliRunner().invoke(app, ["metrics", str(images / "pred.png"),
                                     str(images / "target.png")])
    assert plain.exit_code == 0, plain.output
    assert "PSNR (dB)" in plain.output and "in mask" not in plain.output


def test_metrics_rejects_mixed_inputs_and_bad_masks(app, images, spheres):
    tmp_path, _, _ = spheres
    mixed = CliRunner().invoke(app, ["metrics", str(images / "pred.png"),
                                     str(tmp_path / "scan.ply")])
    assert isinstance(mixed.exception, ValueError) and "not one of each" in str(mixed.exception)
    write_mask(images / "small.png", np.ones((8, 8), dtype=bool))
    small = CliRunner().invoke(app, ["metrics", str(images / "pred.png"),
                                     str(images / "target.png"), "--mask",
                                     str(images / "small.png")])
    assert isinstance(small.exception, ValueError) and "small.png" in str(small.exception)
    meshes = CliRunner().invoke(app, ["metrics", str(tmp_path / "recon.ply"),
                                      str(tmp_path / "scan.ply"), "--mask",
                                      str(images / "mask.png")])
    assert isinstance(meshes.exception, ValueError) and "images only" in str(meshes.exception)
