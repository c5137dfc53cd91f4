"""``lisa view``: help, the missing-extra hint, bad PARAMS as one line, and what it serves
(the server itself is tested in tests/viewer)."""

from __future__ import annotations

import sys

import pytest
import torch
from typer.testing import CliRunner

from lisa_hand.cli import main as cli_main
from lisa_hand.model.trained import export_trained
from lisa_hand.skeleton.params import write_params
from tests.inference.helpers import hand_params, tiny_model


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("view")
    model = tiny_model()
    model_path, _ = export_trained(model, folder / "model.pt")
    hand = hand_params(model, 1)
    hand.model = str(model_path)
    good = write_params(folder / "anna" / "params.json", hand)
    wrong = hand_params(model, 0)
    wrong.shape_code = torch.zeros(5)
    bad_code = write_params(folder / "wrong.json", wrong)
    broken = folder / "broken.json"
    broken.write_text("{not json")
    return {"model": model_path, "good": good, "bad_code": bad_code, "broken": broken}


def _run(args, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli_main.main(args)
    captured = capsys.readouterr()
    return exit_info.value.code, captured.out, captured.err


def test_help_explains_the_viewer():
    result = CliRunner().invoke(cli_main.app, ["view", "--help"], terminal_width=100)
    assert result.exit_code == 0
    for words in ("PARAMS", "--model", "--port", "--host", "--coarse-res", "--fine-res",
                  "skinning weights", "pip install -e '.[view]'"):
        assert words in " ".join(result.output.split()), words


def test_missing_viser_prints_the_install_line(monkeypatch, capsys, files):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser -> ImportError
    code, out, err = _run(["view", str(files["good"])], capsys)
    assert code == 2 and out == ""
    assert err == "lisa: error: lisa view needs the view extra (viser): pip install -e '.[view]'\n"


@pytest.mark.parametrize("which, words", [
    ("broken", "broken.json"),
    ("bad_code", "wrong.json: shape_code has 5 entries"),
    ("missing", "missing.json"),
])
def test_bad_params_is_one_line(which, words, files, capsys, monkeypatch):
    pytest.importorskip("viser", reason="the view extra (viser) is not installed")
    import lisa_hand.viewer.server as server

    monkeypatch.setattr(server, "serve", lambda *a, **k: pytest.fail("served a bad hand"))
    path = files.get(which, files["good"].parent.parent / "missing.json")
    code, _, err = _run(["view", str(path), "--model", str(files["model"])], capsys)
    assert code == 2
    assert err.startswith("lisa: error: ") and err.count("\n") == 1 and words in err, err


def test_serves_the_hands_with_the_mean_hand_and_subjects(files, monkeypatch, capsys):
    pytest.importorskip("viser", reason="the view extra (viser) is not installed")
    import lisa_hand.viewer.server as server

    served = {}
    monkeypatch.setattr(server, "serve", lambda model, hands, config, **kw: served.update(
        model=model, hands=hands, config=config, **kw))
    code, _, err = _run(["view", str(files["good"]), "--port", "8123", "--coarse-res", "24",
                         "--fine-res", "0", "--device", "cpu"], capsys)
    assert code == 0 and err == ""
    names = [hand.name for hand in served["hands"]]
    assert names == ["anna", "mean hand", "subject s0", "subject s1"]
    assert {hand.params.model for hand in served["hands"]} == {str(files["model"].resolve())}
    assert served["config"].port == 8123 and served["config"].remesh.levels() == [("coarse", 24)]
    assert str(served["model_path"]) == str(files["model"])
