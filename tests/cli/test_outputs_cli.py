"""Output paths of every writing command, checked before the work with one-line errors naming
the user's path; a reused fit folder replaced as a whole; a hand in centimetres fitted at its
size."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import lisa_hand.inference
from lisa_hand.cli import main as cli_main
from lisa_hand.handmodel.poses import POSE_NAMES
from lisa_hand.skeleton.params import HandParams, read_params, write_params
from lisa_hand.utils.threads import cpu_threads

FAST_ARGS = ["--iterations", "15", "--restarts", "1", "--res", "40", "--no-progress",
             "--side", "right"]  # one fit, not both sides (--side auto, the default)


def lisa(argv: list[str], capsys) -> tuple[int, str, str]:
    """Run ``lisa`` as the console script does -> (exit status, stdout, stderr)."""
    try:
        cli_main.main(argv)
        code = 0
    except SystemExit as exit_:
        code = exit_.code or 0
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_one_line_error(result: tuple[int, str, str], message: str) -> None:
    code, _, err = result
    assert code == 2, result
    assert err.startswith("lisa: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert "/." not in err  # never a hidden temporary file


@pytest.fixture()
def no_work(monkeypatch):
    """Make loading a hand fail loudly: the output checks must come before it."""
    def refuse(*args, **kwargs):
        raise AssertionError("the work started before the output path was checked")

    monkeypatch.setattr(lisa_hand.inference, "load_hand", refuse)


@pytest.fixture()
def params_file(tmp_path):
    hand = HandParams(pose=torch.zeros(48), translation=torch.zeros(3),
                      rest_joints=torch.arange(48.0).reshape(16, 3) * 0.01,
                      shape_code=torch.zeros(4))
    return write_params(tmp_path / "hand.json", hand)


def test_single_file_outputs_are_checked_before_the_work(tmp_path, params_file, no_work, capsys):
    (tmp_path / "taken.ply").mkdir()
    (tmp_path / "taken.json").mkdir()
    (tmp_path / "afile").write_text("x")
    hand = str(params_file)
    cases = [
        (["mesh", hand, "--out", str(tmp_path / "taken.ply")],
         f"{tmp_path / 'taken.ply'}: is a folder, expected a file name"),
        (["mesh", hand, "--out", str(tmp_path / "afile" / "mesh.ply")],
         f"{tmp_path / 'afile' / 'mesh.ply'}: cannot write here: {tmp_path / 'afile'} is a "
         "file, not a folder"),
        (["blend", hand, hand, "--out", str(tmp_path / "taken.json")],
         f"{tmp_path / 'taken.json'}: is a folder, expected a file name"),
        (["blend", str(tmp_path / "missing.json"), hand, "--out",
          str(tmp_path / "afile" / "p.json")], f"{tmp_path / 'afile' / 'p.json'}: cannot write"),
        (["render", hand, "--orbit", "2", "--out", str(tmp_path / "afile")],
         f"{tmp_path / 'afile'}: is a file, expected a folder"),
        (["render", hand, "--orbit", "2", "--out", str(tmp_path / "afile" / "views")],
         f"{tmp_path / 'afile' / 'views'}: cannot write here"),
        (["animate", hand, "--motion", POSE_NAMES[0], "--out", str(tmp_path / "afile")],
         f"{tmp_path / 'afile'}: is a file, expected a folder"),
    ]
    for argv, message in cases:
        assert_one_line_error(lisa(argv, capsys), message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "hand.json", "taken.json",
                                                         "taken.ply"]


def test_blend_into_a_folder_names_it(tmp_path, params_file, capsys):
    (tmp_path / "out").mkdir()
    assert_one_line_error(
        lisa(["blend", str(params_file), str(params_file), "--out", str(tmp_path / "out")],
             capsys),
        f"{tmp_path / 'out'}: is a folder, expected a file name")
    code, out, _ = lisa(["blend", str(params_file), str(params_file), "--out",
                         str(tmp_path / "out" / "mixed.json")], capsys)
    assert code == 0 and "wrote" in out
    assert read_params(tmp_path / "out" / "mixed.json").shape_code.shape == (4,)


@pytest.fixture(scope="module")
def fit_files(tmp_path_factory):
    """A tiny colour model, a scan of its own surface (metres and centimetres), the true mesh."""
    from lisa_hand.data.meshio import save_mesh
    from lisa_hand.data.scans import ScanConfig
    from lisa_hand.model.trained import export_trained
    from tests.fitting.test_points import scan_of, surface, tiny_model, true_hand

    with cpu_threads(1):
        root = tmp_path_factory.mktemp("fit_outputs")
        model = tiny_model(color=True)
        truth = true_hand(model, seed=2)
        points, normals, _ = scan_of(model, truth, ScanConfig(num_points=600), seed=2)
        export_trained(model, root / "tiny.pt")
        np.savez(root / "scan.npz", points=points, normals=normals)
        np.save(root / "scan_cm.npy", 100.0 * points)
        save_mesh(root / "truth.ply", surface(model, truth))
    return root, points


def test_a_reused_fit_folder_is_replaced_as_a_whole(fit_files, capsys):
    root, _ = fit_files
    out = root / "reused"
    model = ["--model", str(root / "tiny.pt")]
    code, _, err = lisa(["fit-points", str(root / "scan.npz"), "--out", str(out), *model,
                         "--gt", str(root / "truth.ply"), *FAST_ARGS], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "metrics.json",
                                                     "params.json", "preview.png"]
    # The same folder, another cloud, no --gt: the first fit's metrics.json does not survive.
    code, _, err = lisa(["fit-points", str(root / "scan_cm.npy"), "--out", str(out), *model,
                         *FAST_ARGS], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "params.json",
                                                     "preview.png"]
    assert read_params(out / "params.json").extra["input"]["path"].endswith("scan_cm.npy")
    assert not [p for p in root.iterdir() if p.name.startswith(".reused.")]
    # A folder holding files a fit does not write is refused before the fit, and kept.
    (out / "notes.txt").write_text("mine")
    assert_one_line_error(
        lisa(["fit-points", str(root / "scan.npz"), "--out", str(out), *model, *FAST_ARGS],
             capsys),
        f"{out}: output folder holds files a fit does not write (notes.txt)")
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "notes.txt",
                                                     "params.json", "preview.png"]


def test_a_hand_in_centimetres_is_fitted_at_its_size(fit_files, capsys):
    root, points = fit_files
    out = root / "out_cm"
    code, printed, err = lisa(["fit-points", str(root / "scan_cm.npy"), "--out", str(out),
                               "--model", str(root / "tiny.pt"), *FAST_ARGS], capsys)
    assert code == 0, err
    assert "scan_cm.npy: the cloud is" in printed and "read as centimetres" in printed
    params = read_params(out / "params.json")
    assert params.extra["input"]["unit"] == "cm"
    assert np.linalg.norm(params.translation.numpy() - points.mean(0)) < 0.1  # metres
    # --units cm says so; --units m on it (a hand 20 m across) names the unit that fits.
    code, printed, err = lisa(["fit-points", str(root / "scan_cm.npy"), "--out", str(out),
                               "--units", "cm", "--model", str(root / "tiny.pt"), *FAST_ARGS],
                              capsys)
    assert code == 0 and "read as" not in printed, err
    assert_one_line_error(
        lisa(["fit-points", str(root / "scan_cm.npy"), "--out", str(root / "never"), "--units",
              "m", "--model", str(root / "tiny.pt"), *FAST_ARGS], capsys),
        "looks like centimetres: pass --units cm")
    assert not (root / "never").exists()


def test_error_line_is_one_line_naming_the_path():
    raised = None
    try:
        open("/")  # noqa: SIM115 - the system's own error, as a writer would meet it
    except OSError as exc:
        raised = exc
    assert cli_main.error_line(raised) == "/: Is a directory"
    assert cli_main.error_line(ValueError("first\n  second\n")) == "first; second"
    assert cli_main.error_line(FileNotFoundError("x.ply: no such file")) == "x.ply: no such file"


@pytest.mark.parametrize("argv, status", [(["--help"], 0), (["fit-points", "nope.ply"], 2)])
def test_a_torchrun_worker_ends_through_end_process(monkeypatch, capsys, argv, status):
    """Under torchrun (a process group created), main() ends the process with the command's
    status through end_process (no interpreter teardown with gloo's threads alive); otherwise it
    raises SystemExit as usual."""
    ended = []

    def fake_end(code):
        ended.append(code)
        raise SystemExit(code)  # the real one never returns

    monkeypatch.setattr(cli_main, "end_process", fake_end)
    with pytest.raises(SystemExit):
        cli_main.main(argv)
    assert ended == []
    monkeypatch.setattr(cli_main, "group_was_created", lambda: True)
    with pytest.raises(SystemExit):
        cli_main.main(argv)
    assert ended == [status]
    assert [cli_main._exit_status(code) for code in (None, 0, 3)] == [0, 0, 3]
    assert cli_main._exit_status("bye") == 1 and capsys.readouterr().err.endswith("bye\n")
