import json

import numpy as np
import pytest
import trimesh
import typer
from typer.testing import CliRunner

from lisa_hand.cli import main as cli_main
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
    assert ("scan_mm.npy: the point set is 183.6 units across: read as millimetres"
            in result.output)
    assert "n/a" in result.output and "has no faces" in result.output
    values = json.loads(out.read_text())
    assert values["v2s_recon_to_scan_mm"] is None
    assert values["v2v_recon_to_scan_mm"] == pytest.approx(3.0, abs=1e-5)
    # Forcing metres on the millimetre file would read a 184 m hand (53 m distances): refused,
    # naming the file and the unit that fits.
    out.unlink()
    forced = CliRunner().invoke(
        app, ["metrics", str(tmp_path / "recon.ply"), str(tmp_path / "scan_mm.npy"),
              "--units", "m", "--json", str(out)]
    )
    assert forced.exit_code != 0 and isinstance(forced.exception, ValueError)
    assert "scan_mm.npy: the point set is 183.6 units across: as metres that is 184 m, too large " \
        "for a hand" in str(forced.exception)
    assert "looks like millimetres: pass --units mm" in str(forced.exception)
    assert not out.exists()


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


def lisa(argv: list[str], capsys) -> tuple[int, str, str]:
    """Run ``lisa`` as the console script does -> (exit status, stdout, stderr)."""
    try:
        cli_main.main(argv)
        code = 0
    except SystemExit as exit_:
        code = exit_.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_one_line_error(result: tuple[int, str, str], message: str) -> None:
    code, _, err = result
    assert code == 2, result
    assert err.startswith("lisa: error: ") and err.endswith("\n") and err.count("\n") == 1, err
    assert message in err, err


def test_metrics_reads_centimetres_and_refuses_a_unit_that_makes_no_hand(spheres, capsys):
    tmp_path, _, outer = spheres
    np.save(tmp_path / "scan_cm.npy", 100.0 * outer.vertices)  # 18 units across
    np.save(tmp_path / "scan_mm.npy", 1000.0 * outer.vertices)
    code, out, _ = lisa(["metrics", str(tmp_path / "recon.ply"), str(tmp_path / "scan_cm.npy")],
                        capsys)
    assert code == 0
    assert "scan_cm.npy: the point set is 18.36 units across: read as centimetres" in out
    assert "V2V recon -> scan     3.0000" in out
    assert_one_line_error(
        lisa(["metrics", str(tmp_path / "recon.ply"), str(tmp_path / "scan_mm.npy"), "--units",
              "m"], capsys),
        "scan_mm.npy: the point set is 183.6 units across: as metres that is 184 m")
    assert_one_line_error(
        lisa(["metrics", str(tmp_path / "scan_cm.npy"), str(tmp_path / "recon.ply"), "--units",
              "cm"], capsys),
        "recon.ply: the mesh is 0.1732 units across: as centimetres that is 1.73 mm, too small "
        "for a hand")
    code, out, _ = lisa(["metrics", str(tmp_path / "scan_cm.npy"), str(tmp_path / "scan_cm.npy"),
                         "--units", "cm"], capsys)
    assert code == 0 and "V2V recon -> scan     0.0000" in out


def test_metrics_bad_paths_are_one_line_errors_before_the_work(spheres, images, capsys):
    tmp_path, _, _ = spheres
    recon, scan = str(tmp_path / "recon.ply"), str(tmp_path / "scan.ply")
    (tmp_path / "taken").mkdir()
    (tmp_path / "afile").write_text("x")
    (tmp_path / "folder.ply").mkdir()
    (tmp_path / "faces.ply").write_text("ply\nformat ascii 1.0\nelement face 1\nproperty list "
                                        "uchar int vertex_indices\nend_header\n3 0 1 2\n")
    (images / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n not really")
    (images / "text.png").write_text("not an image")
    cases = [
        ([recon, scan, "--json", str(tmp_path / "taken")], "taken: is a folder, expected a file"),
        ([recon, scan, "--json", str(tmp_path / "afile" / "m.json")],
         "afile/m.json: cannot write here: "),
        ([str(tmp_path / "folder.ply"), scan], "folder.ply: is a directory, expected a file"),
        ([recon, str(tmp_path / "faces.ply")], "faces.ply: the PLY has 1 face(s) but no vertex"),
        ([str(images / "corrupt.png"), str(images / "target.png")],
         "corrupt.png: not a readable image"),
        ([str(images / "text.png"), str(images / "target.png")],
         "text.png: not a readable image (not a PNG or JPEG file, or a corrupt one)"),
        ([str(images / "pred.png"), str(images / "target.png"), "--json", str(tmp_path / "taken")],
         "taken: is a folder, expected a file"),
    ]
    for arguments, message in cases:
        assert_one_line_error(lisa(["metrics", *arguments], capsys), message)
    assert sorted(p.name for p in (tmp_path / "taken").iterdir()) == []
