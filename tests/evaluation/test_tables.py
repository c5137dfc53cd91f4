"""``lisa eval``: the quick mode end to end (tiny dataset, every method trained a few steps,
the three tables), resuming, the tables' arithmetic, and the checks of its input.

The quick models are barely trained: the test checks that every stage runs and measures in
millimetres and decibels, not which method wins.
"""

from __future__ import annotations

import json
import math

import pytest

from lisa_hand.cli import main as cli_main
from lisa_hand.evaluation.methods import METHODS, check_model_method
from lisa_hand.evaluation.quick import quick_config, quick_models
from lisa_hand.evaluation.tables import DISTANCES, build_results, markdown_tables, run_eval
from lisa_hand.model.trained import load_trained
from lisa_hand.utils.threads import cpu_threads

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """The quick mode's dataset and models (10 training steps each)."""
    with cpu_threads(1):
        return quick_models(tmp_path_factory.mktemp("quick"), steps=10, log=lambda line: None)


def test_quick_models_are_the_paper_baselines(quick):
    _, models = quick
    assert list(models) == ["volsdf", "nasa", "narf", "lisa_im", "lisa_geom", "lisa_full"]
    for method, path in models.items():
        model = load_trained(path)
        check_model_method(method, model, path)  # composition and colour match the method
        field = model.field
        per_bone = [p for p in field.parameters() if p.shape[0] == 16]
        if method == "volsdf":  # one MLP, nothing per bone
            assert not per_bone and field.skinning_mlp is None
        else:  # per-bone SDF MLPs, and per-bone colour MLPs for the image-trained ones
            assert per_bone and field.sdf_mlp is not None
            assert (field.color_mlp is not None) == (method != "lisa_geom")
        # NASA selects a bone (no skinning MLP); NARF's and LISA's weights come from an MLP
        # whose input is the unposed points (NARF) or the unposed points and the SDFs (LISA).
        assert (field.skinning_mlp is None) == (method in ("volsdf", "nasa"))
    with pytest.raises(ValueError, match="cannot be NASA"):
        check_model_method("nasa", load_trained(models["lisa_im"]), models["lisa_im"])
    with pytest.raises(ValueError, match="has none"):
        check_model_method("lisa_full", load_trained(models["lisa_geom"]), models["lisa_geom"])


def test_quick_eval_end_to_end_and_resume(quick, tmp_path):
    data, models = quick
    out = tmp_path / "eval"
    lines: list[str] = []
    result = run_eval(data, models, out, quick_config(), log=lines.append, progress=False)
    results = json.loads((out / "results.json").read_text())

    # Table 1: both test sets, every method (the MANO-like template included), four finite
    # distances in millimetres (a hand is ~200 mm long: an error over 100 mm is not mm).
    assert set(results["table1"]) == {"subjects", "poses"}
    for table in results["table1"].values():
        assert list(table) == list(METHODS)
        for row in table.values():
            for key in DISTANCES:
                assert 0.01 < row[key] < 100.0, (key, row)
    assert results["table1"]["poses"]["mano"]["count"] == 2
    # Tables 2 and 3: the quick view counts; colour methods have PSNR (dB) and SSIM; the
    # MANO-like row and the geometry-only prior have no colour.
    assert set(results["table2"]) == {"1", "4"}
    for count, table in results["table2"].items():
        assert "lisa_geom" not in table and table["mano"]["psnr_db"] is None
        for method, row in table.items():
            assert 0.01 < row["v2s_scan_to_recon_mm"] < 100.0, (count, method)
            if method != "mano":
                assert 5.0 < row["psnr_db"] < 60.0
                assert 0.0 < results["table3"][count][method]["ssim"] <= 1.0
    lpips_values = [row["lpips"] for table in results["table3"].values()
                    for row in table.values()]
    if results["lpips_note"]:  # LPIPS's weights are not installed: empty column, a reason
        assert all(value is None for value in lpips_values)
        assert results["lpips_note"] in result.markdown
    else:
        assert all(0.0 <= value <= 1.0 for value in lpips_values)

    # The Markdown holds the three tables, printed as the run's last lines.
    markdown = (out / "results.md").read_text()
    for title in ("Table 1", "Table 2", "Table 3"):
        assert f"### {title}" in markdown
    assert markdown.count("| MANO-like |") == 3  # two sets in Table 1, one row in Table 2
    assert result.markdown in "\n".join(lines)
    for picture in results["pictures"]:
        assert (out / picture).stat().st_size > 1000

    # Every fit is kept: the same call resumes with nothing left to do and the same tables.
    again: list[str] = []
    second = run_eval(data, models, out, quick_config(), log=again.append, progress=False)
    assert any(line.startswith("resuming: 23 fits already done") for line in again)
    assert second.results["table1"] == result.results["table1"]


def _row(method, value, **extra):
    return {"method": method, "frame_name": "f", "seconds": 1.0,
            **{key: value for key in DISTANCES}, **extra}


def test_tables_average_the_fits_and_bold_the_best():
    point_rows = [{**_row("mano", 2.0), "set": "subjects"},
                  {**_row("mano", 4.0), "set": "subjects"},
                  {**_row("nasa", 1.0), "set": "subjects"}, {**_row("nasa", 5.0), "set": "poses"}]
    image_rows = [{**_row("mano", 8.0), "num_views": 1, "psnr_db": None, "ssim": None,
                   "lpips": None},
                  {**_row("nasa", 6.0), "num_views": 1, "psnr_db": 20.0, "ssim": 0.9,
                   "lpips": None, "lpips_message": "not installed"}]
    results = build_results(point_rows, image_rows, list(METHODS))
    assert results["table1"]["subjects"]["mano"]["v2s_scan_to_recon_mm"] == 3.0
    assert results["table1"]["subjects"]["mano"]["count"] == 2
    assert results["table1"]["poses"] == {"nasa": {**{k: 5.0 for k in DISTANCES}, "count": 1,
                                                   "seconds": 1.0}}
    assert results["table2"]["1"]["mano"]["psnr_db"] is None
    assert list(results["table3"]["1"]) == ["nasa"] and results["lpips_note"] == "not installed"
    markdown = markdown_tables(results)
    assert "| NASA | **1.00** | **1.00** | **1.00** | **1.00** | 1 |" in markdown
    assert "| MANO-like | 3.00 | 3.00 | 3.00 | 3.00 | 1 |" in markdown
    assert "| MANO-like | 8.00 | 8.00 | - |" in markdown
    assert "| NASA | **6.00** | **6.00** | **20.00** |" in markdown
    assert "\nnot installed\n" in markdown
    assert not math.isnan(results["table2"]["1"]["nasa"]["psnr_db"])


def test_eval_command_checks_its_input(quick, tmp_path, capsys):
    data, models = quick

    def error(*args):
        with pytest.raises(SystemExit) as info:
            cli_main.main(["eval", *map(str, args)])
        assert info.value.code == 2
        message = capsys.readouterr().err.strip()
        assert message.startswith("lisa: error: ") and "\n" not in message
        return message

    assert "expected METHOD=PATH" in error(data, "--out", tmp_path / "e", "--model", "nasa")
    assert "unknown method 'mano'" in error(data, "--out", tmp_path / "e", "--model",
                                            f"mano={models['nasa']}")
    assert "cannot be NARF" in error(data, "--out", tmp_path / "e", "--model",
                                     f"narf={models['nasa']}")
    assert "DATA is required" in error("--out", tmp_path / "e")
    assert "not a dataset folder" in error(tmp_path, "--out", tmp_path / "e")
    assert "views must be" in error(data, "--out", tmp_path / "e", "--views", "3")
    assert "nowhere: no such model file, run folder or shipped model (nasa)" in error(
        data, "--out", tmp_path / "e", "--model", "nasa=nowhere")
    # A shipped model by name passes the path check and reaches the method check.
    assert "geometry: a 'lisa' model cannot be NASA" in error(data, "--out", tmp_path / "e",
                                                              "--model", "nasa=geometry")


def test_eval_quick_command_needs_nothing(tmp_path, capsys):
    """``lisa eval --quick`` with no data and no models: it makes both, then the tables."""
    out = tmp_path / "quick_eval"
    with pytest.raises(SystemExit) as info:
        cli_main.main(["eval", "--quick", "--out", str(out)])
    assert info.value.code == 0
    printed = capsys.readouterr().out
    results = json.loads((out / "results.json").read_text())
    assert set(results["models"]) == {"volsdf", "nasa", "narf", "lisa_im", "lisa_geom",
                                      "lisa_full"}
    assert results["config"]["resolution"] == 48 and results["config"]["views"] == [1, 4]
    for table in results["table1"].values():
        for row in table.values():
            assert all(0.01 < row[key] < 100.0 for key in DISTANCES)
    assert "### Table 3" in printed and "eval finished in" in printed
    assert (out / "quick" / "data" / "split.json").is_file()
