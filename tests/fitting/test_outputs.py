"""What a fit writes: the output folder replaced as a whole, checked before the work; the
ground truth read in the unit of a hand's size."""

import os
import stat

import numpy as np
import pytest
import torch

from lisa_hand.fitting.outputs import (
    FIT_FILES,
    check_output_folder,
    read_ground_truth,
    remove_stale_staging,
    write_fit_outputs,
)
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.skeleton.params import HandParams, read_params


def hand(x: float = 0.0) -> HandParams:
    return HandParams(pose=torch.zeros(48), translation=torch.tensor([x, 0.0, 0.0]),
                      rest_joints=torch.arange(48.0).reshape(16, 3) * 0.01,
                      shape_code=torch.zeros(4))


MESH = Mesh(vertices=np.eye(3), faces=np.array([[0, 1, 2]]))


def test_a_reused_folder_is_replaced_as_a_whole(tmp_path):
    out = tmp_path / "fit"
    write_fit_outputs(out, hand(1.0), MESH, {"v2v_recon_to_scan_mm": 3.0})
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "metrics.json",
                                                     "params.json"]
    out.chmod(0o750)
    # A second fit without metrics: the first fit's metrics.json (of another hand) is gone.
    written = write_fit_outputs(out, hand(2.0), MESH)
    assert [p.name for p in written] == ["params.json", "mesh.ply", "keypoints.json"]
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "params.json"]
    assert float(read_params(out / "params.json").translation[0]) == 2.0
    assert stat.S_IMODE(out.stat().st_mode) == 0o750  # the folder keeps its permissions
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"]  # no staging or old folder


def test_a_folder_with_other_files_is_refused_before_the_work(tmp_path):
    out = tmp_path / "fit"
    out.mkdir()
    (out / "params.json").write_text("{}")
    (out / "notes.txt").write_text("mine")
    (out / "renders").mkdir()
    with pytest.raises(FileExistsError, match=r"fit: output folder holds files a fit does not "
                                              r"write \(notes\.txt, renders\)"):
        check_output_folder(out)
    with pytest.raises(FileExistsError, match="notes.txt"):
        write_fit_outputs(out, hand(), MESH)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "params.json", "renders"]
    assert set(FIT_FILES) == {"params.json", "mesh.ply", "keypoints.json", "metrics.json",
                              "model.pt", "preview.png"}
    check_output_folder(tmp_path / "new" / "fit")  # creates nothing
    assert not (tmp_path / "new").exists()


def test_staging_folders_of_killed_fits_are_removed_by_the_next_fit(tmp_path):
    out = tmp_path / "fit"
    dead = 2**22 + 12345  # above the kernel's largest pid_max (2^22): no process has this id
    stale = tmp_path / f".fit.staging-{dead}-abc123"
    old = tmp_path / f".fit.old-{dead}-0a1b2c3d"
    running = tmp_path / f".fit.staging-{os.getpid()}-xyz"  # a fit writing right now
    other = tmp_path / f".other.staging-{dead}-abc"  # another folder's
    for folder in (stale, old, running, other):
        folder.mkdir()
        (folder / "params.json").write_text("{}")
    assert remove_stale_staging(out) == [old, stale]
    write_fit_outputs(out, hand(), MESH)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["fit", running.name,
                                                                 other.name])


def test_the_working_folder_is_refilled_file_by_file(tmp_path, monkeypatch):
    out = tmp_path / "fit"
    write_fit_outputs(out, hand(1.0), MESH, {"psnr_db": 20.0})
    monkeypatch.chdir(out)  # it cannot be renamed away: the files are replaced one by one
    write_fit_outputs(".", hand(2.0), MESH)
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "params.json"]
    assert float(read_params(out / "params.json").translation[0]) == 2.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"]


def test_ground_truth_in_centimetres(tmp_path):
    vertices = np.random.default_rng(0).uniform(-0.05, 0.05, size=(200, 3))  # 0.17 m across
    np.save(tmp_path / "gt_cm.npy", 100.0 * vertices)
    truth = read_ground_truth(tmp_path / "gt_cm.npy")
    assert truth.unit == "cm" and truth.note.startswith(f"{tmp_path / 'gt_cm.npy'}: the ground "
                                                        "truth is 17.")
    assert "read as centimetres" in truth.note
    np.testing.assert_allclose(truth.vertices, vertices, rtol=1e-12)
    assert read_ground_truth(tmp_path / "gt_cm.npy", units="cm").note is None
    with pytest.raises(ValueError, match=r"gt_cm\.npy: the ground truth is .* as millimetres "
                                         r"that is 17\.\d mm, too small for a hand.*looks like "
                                         "centimetres: pass --units cm"):
        read_ground_truth(tmp_path / "gt_cm.npy", units="mm")


KILLED_WRITER = """
import sys, time
import numpy as np, torch
import lisa_hand.data.meshio as meshio
from lisa_hand.fitting.outputs import write_fit_outputs
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.skeleton.params import HandParams

def stuck(path, mesh):
    open(path, "w").write("half a mesh")
    print("writing", flush=True)
    time.sleep(120)

meshio.save_mesh = stuck
hand = HandParams(pose=torch.zeros(48), translation=torch.zeros(3),
                  rest_joints=torch.arange(48.0).reshape(16, 3) * 0.01,
                  shape_code=torch.zeros(4))
write_fit_outputs(sys.argv[1], hand, Mesh(vertices=np.eye(3), faces=np.array([[0, 1, 2]])))
"""


def test_a_kill_during_the_write_keeps_the_previous_fit_and_the_next_fit_cleans_up(tmp_path):
    import subprocess
    import sys

    out = tmp_path / "fit"
    write_fit_outputs(out, hand(1.0), MESH, {"psnr_db": 20.0})
    writer = subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(out)],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert writer.stdout.readline().strip() == "writing"
    finally:
        writer.kill()  # SIGKILL: no cleanup runs
        writer.wait()
        writer.stdout.close()
    # The killed writer's claim (.fit.lock, its dead pid) is taken over by the next fit.
    assert (tmp_path / ".fit.lock").read_text().split()[0] == str(writer.pid)
    staging = [p.name for p in tmp_path.iterdir() if p.name not in ("fit", ".fit.lock")]
    assert len(staging) == 1 and staging[0].startswith(f".fit.staging-{writer.pid}-")
    assert sorted(p.name for p in out.iterdir()) == ["keypoints.json", "mesh.ply", "metrics.json",
                                                     "params.json"]
    assert float(read_params(out / "params.json").translation[0]) == 1.0  # intact
    write_fit_outputs(out, hand(2.0), MESH)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"]


def test_the_one_writer_writes_any_artefacts_in_their_folders(tmp_path):
    """write_fit: artefacts in sub-folders, written in order, all or nothing; a fitter's own
    rule of what a previous fit leaves; names are unique."""
    import json

    from lisa_hand.fitting.outputs import (
        Artefact,
        json_artefact,
        mask_artefact,
        text_artefact,
        write_fit,
    )

    def photo_like(path):
        return path.name in ("a.json", "note.html", "mask.png") or path.name == "hand0"

    out = tmp_path / "fit"
    artefacts = [json_artefact("a.json", {"x": float("nan")}),
                 text_artefact("hand0/note.html", "<p>é</p>"),
                 mask_artefact("hand0/mask.png", np.eye(4, dtype=bool))]
    written = write_fit(out, artefacts, photo_like, "a.json and hand0/")
    assert written == [out / "a.json", out / "hand0" / "note.html", out / "hand0" / "mask.png"]
    assert json.loads((out / "a.json").read_text()) == {"x": None}
    assert (out / "hand0" / "note.html").read_text(encoding="utf-8") == "<p>é</p>"

    def broken(path):
        raise RuntimeError("no picture")

    with pytest.raises(RuntimeError, match="no picture"):
        write_fit(out, [json_artefact("a.json", {"x": 2}), Artefact("hand0/mask.png", broken)],
                  photo_like)
    assert json.loads((out / "a.json").read_text()) == {"x": None}  # the folder as it was
    with pytest.raises(ValueError, match="distinct names"):
        write_fit(out, [json_artefact("a.json", {}), json_artefact("a.json", {})], photo_like)
    with pytest.raises(FileExistsError, match="hand0"):
        write_fit(out, [json_artefact("a.json", {})])  # the default rule: FIT_FILES only
