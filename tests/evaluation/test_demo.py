"""``lisa demo`` end to end on a tiny exported model (the shipped model is not needed): the three
fits, their files, the table, the turntable and the self-contained report; and its checks of
bad input before anything is written.

The tiny model is an untrained LISA (geometric initialisation, a blob hand with colour): the
numbers are not the demo's, only the pipeline is (about 10 s on one CPU thread).
"""

from __future__ import annotations

import math
import re

import imageio.v3 as iio
import pytest

from lisa_hand.cli import main as cli_main
from lisa_hand.evaluation.demo import DemoConfig, run_demo
from lisa_hand.model.trained import export_trained
from tests.fitting.test_points import tiny_model

METRICS = ("v2v_recon_to_scan_mm", "v2s_recon_to_scan_mm", "v2v_scan_to_recon_mm",
           "v2s_scan_to_recon_mm")


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    """A tiny colour model exported as ``lisa demo --model`` takes it."""
    path, _ = export_trained(tiny_model(color=True), tmp_path_factory.mktemp("demo") / "tiny.pt")
    return path


def tiny_config(model_file, **overrides) -> DemoConfig:
    """The demo at toy sizes: 48 x 36 images, 5 views (4 fitted, 1 novel), 24^3 meshes, a
    2-frame turntable of 32 x 32, 5% of the fits' iterations."""
    values = dict(model=str(model_file), resolution=(48, 36), num_views=5, mesh_resolution=24,
                  orbit_views=2, orbit_size=32, fit_scale=0.05, device="cpu")
    values.update(overrides)
    return DemoConfig(**values)


def test_demo_fits_measures_renders_and_reports(model_file, tmp_path):
    out = tmp_path / "demo"
    lines: list[str] = []
    result = run_demo(out, tiny_config(model_file), log=lines.append)

    # Progress: every step is announced, then the table and where the report is.
    for step in ("1/5 synthesizing", "2/5 fitting to the point cloud", "3/5 fitting to the 1 view",
                 "4/5 fitting to the 4 views", "5/5 rendering a turntable"):
        assert any(line.startswith(step) for line in lines), step
    assert lines[-1].startswith("demo finished in") and str(result.report) in lines[-1]

    # The table: the three fits, the four distances (mm) and the PSNR on the novel view.
    assert [row["method"] for row in result.rows] == ["LISA, point cloud", "LISA, 1 view",
                                                      "LISA, 4 views"]
    for row in result.rows:
        assert all(math.isfinite(row[key]) and row[key] > 0 for key in METRICS), row
        assert math.isfinite(row["psnr_db"]) and row["psnr_db"] > 0
        assert math.isfinite(row["psnr_calibrated_db"]) and row["psnr_calibrated_db"] > 0
        assert row["seconds"] > 0
    table = (out / "results.md").read_text()
    assert table.count("\n| LISA, ") == 3 and table.strip() in "\n".join(lines)

    # Each fit wrote its files (all four, metrics against the true mesh).
    for folder in ("fit_points", "fit_1view", "fit_4views"):
        assert sorted(p.name for p in (out / folder).iterdir()) == [
            "keypoints.json", "mesh.ply", "metrics.json", "params.json",
            *(["preview.png"] if folder == "fit_points" else [])], folder
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no staging folder left

    # The turntable of the 4-view fit: one frame per orbit view.
    gif = iio.imread(out / "turntable" / "turntable.gif", index=None)
    assert gif.shape[:3] == (2, 32, 32)

    # The report is one self-contained file: every picture is embedded, nothing is linked.
    page = result.report.read_text(encoding="utf-8")
    sources = re.findall(r"src='([^']*)'", page)
    assert sources and all(src.startswith("data:image/") for src in sources)
    assert any(src.startswith("data:image/gif;base64,") for src in sources)
    assert "href=" not in page and page.count("<tr><td>LISA, ") == 3
    assert "The point-cloud fit and its scan" in page  # fit_points/preview.png, embedded

    # The calibrated PSNR renders each novel view with that camera's gain and bias from the
    # frame's truth: given the model's own mean calibration there, it is the plain PSNR; a
    # wrong response there lowers it.
    import json

    from lisa_hand.data.layout import FramePaths
    from lisa_hand.evaluation.demo import _novel_view_psnr
    from lisa_hand.model.trained import load_trained
    from lisa_hand.skeleton.params import read_params

    model = load_trained(model_file, "cpu")
    frame = FramePaths(out / "input" / "s000" / "f000")
    params = read_params(out / "fit_4views" / "params.json")
    truth = json.loads(frame.params.read_text())
    novel = [name for name in truth["camera_gain"] if name not in ("cam000", "cam001", "cam002",
                                                                    "cam003")]
    assert len(novel) == 1
    for name in novel:
        truth["camera_gain"][name] = model.gain.tolist()
        truth["camera_bias"][name] = model.bias.tolist()
    frame.params.write_text(json.dumps(truth))
    plain, calibrated, _ = _novel_view_psnr(model, params, frame, novel)
    assert calibrated == pytest.approx(plain, abs=1e-9)
    truth["camera_bias"][novel[0]] = [0.3, -0.2, 0.25]
    frame.params.write_text(json.dumps(truth))
    _, shifted, _ = _novel_view_psnr(model, params, frame, novel)
    assert shifted < plain - 3.0


def test_demo_rejects_bad_input_before_writing(model_file, tmp_path):
    out = tmp_path / "demo"
    with pytest.raises(ValueError, match="num_views must be >= 5"):
        run_demo(out, tiny_config(model_file, num_views=4), log=lambda line: None)
    with pytest.raises(ValueError, match="hand_model must be one of v1, v2, v3, got 'v4'"):
        run_demo(out, tiny_config(model_file, hand_model="v4"), log=lambda line: None)
    with pytest.raises(FileNotFoundError, match="nothing.pt: no such model file"):
        run_demo(out, tiny_config(tmp_path / "nothing.pt"), log=lambda line: None)
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"\x00garbage" * 100)
    with pytest.raises(ValueError, match="corrupt.pt: not a LISA model file"):
        run_demo(out, tiny_config(corrupt), log=lambda line: None)
    assert not out.exists()  # nothing half-written


def test_demo_command_reports_a_corrupt_model_in_one_line(tmp_path, capsys):
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"\x00garbage" * 100)
    out = tmp_path / "demo"
    with pytest.raises(SystemExit) as info:
        cli_main.main(["demo", "--out", str(out), "--model", str(corrupt), "--device", "cpu"])
    assert info.value.code == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("lisa: error: ") and "corrupt.pt: not a LISA model file" in error
    assert "\n" not in error and not out.exists()
    with pytest.raises(SystemExit) as info:
        cli_main.main(["demo", "--out", str(out), "--fit-scale", "0"])
    assert info.value.code == 2 and "--fit-scale must be > 0" in capsys.readouterr().err
