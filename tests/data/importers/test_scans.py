"""``lisa import scans``: scan.npz with skinning pseudo ground truth from the template or MANO."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lisa_hand.data.datasets import ScanFrames
from lisa_hand.data.importers.scans import ScanImportConfig, import_scans
from lisa_hand.data.layout import read_npz
from lisa_hand.data.meshio import save_mesh
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.handmodel.poses import sample_pose
from lisa_hand.handmodel.template import load_template
from lisa_hand.skeleton import ManoLayer
from tests.skeleton.synthetic_mano import write_synthetic_mano

F64 = torch.float64


def test_template_scans_get_the_template_weights(tmp_path):
    template = load_template().to(dtype=F64)
    pose = sample_pose(torch.Generator().manual_seed(0), 2, global_orient=True).to(F64)
    betas = torch.zeros(2, template.num_betas, dtype=F64)
    posed = template(pose, betas, torch.tensor([[0.0, 0.1, 0.5], [0.1, 0.0, 0.5]], dtype=F64))
    folder = tmp_path / "scans" / "alice"
    folder.mkdir(parents=True)
    for i in range(2):
        # In millimetres, as many scanners write: the unit is detected from the size.
        save_mesh(folder / f"scan{i}.ply", Mesh(vertices=posed.vertices[i].numpy() * 1e3,
                                                faces=template.faces.numpy()))
        (folder / f"scan{i}.keypoints3d.json").write_text(json.dumps(
            {"keypoints": (posed.keypoints[i].numpy() * 1e3).tolist(), "side": "right"}))
    (folder / "unposed.ply").write_bytes((folder / "scan0.ply").read_bytes())
    out = tmp_path / "DATA"
    report = import_scans(ScanImportConfig(root=str(tmp_path / "scans"), num_points=2000,
                                           num_sdf_samples=500), out, progress=False)
    assert report.num_frames == 2 and report.num_subjects == 1
    assert report.skipped == {"no pose": 1}
    scans = ScanFrames(out, "train")
    assert scans.num_frames == 2
    for i in range(2):
        arrays = read_npz(out / "s000" / f"f00{i}" / "scan.npz")
        # Independent reference: the weights of the nearest vertex of the true posed template.
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(posed.vertices[i].numpy()).query(arrays["points"])
        expected = template.weights.numpy()[nearest]
        # The pose is the IK's (its twist about each bone is a choice), so the nearest vertex
        # often is a neighbour of the true one, with nearly the same weights.
        l1 = np.abs(arrays["template_weights"] - expected).sum(axis=1)
        print(f"scan {i}: mean L1 {l1.mean():.4f}, dominant bone agrees "
              f"{(arrays['template_weights'].argmax(1) == expected.argmax(1)).mean():.3f}")
        assert l1.mean() < 0.15
        assert (arrays["template_weights"].argmax(1) == expected.argmax(1)).mean() > 0.9
        assert np.abs(arrays["points"]).max() < 1.0  # metres
        assert np.abs(arrays["sdf"]).max() < 0.05


def test_mano_scans_get_mano_weights(tmp_path):
    mano_dir = tmp_path / "mano"
    mano_dir.mkdir()
    write_synthetic_mano(mano_dir / "MANO_LEFT.pkl", "left", seed=4)
    layer = ManoLayer(mano_dir / "MANO_LEFT.pkl", dtype=F64)
    rng = np.random.default_rng(0)
    entry = {"pose": (0.3 * rng.standard_normal(48)).tolist(),
             "shape": rng.standard_normal(10).tolist(), "trans": [0.0, 0.0, 0.4], "side": "left"}
    out = layer(hand_pose=torch.tensor([entry["pose"][3:]], dtype=F64),
                global_orient=torch.tensor([entry["pose"][:3]], dtype=F64),
                betas=torch.tensor([entry["shape"]], dtype=F64),
                transl=torch.tensor([entry["trans"]], dtype=F64))
    vertices = out.vertices[0].numpy()
    normals = rng.standard_normal(vertices.shape)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    # A point cloud with normals: exactly the MANO vertices.
    folder = tmp_path / "scans"
    folder.mkdir()
    header = ("ply\nformat ascii 1.0\nelement vertex 778\nproperty float x\nproperty float y\n"
              "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
              "end_header\n")
    body = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in np.hstack([vertices,
                                                                            normals]))
    (folder / "bob.ply").write_text(header + body + "\n")
    (folder / "bob.mano.json").write_text(json.dumps(entry))
    data = tmp_path / "DATA"
    report = import_scans(ScanImportConfig(root=str(folder), units="m", num_points=778,
                                           num_sdf_samples=100, mano=str(mano_dir)), data,
                          progress=False)
    assert report.pose_source == {"mano": 1}
    arrays = read_npz(data / "s000" / "f000" / "scan.npz")
    _, nearest = __import__("scipy.spatial", fromlist=["cKDTree"]).cKDTree(vertices).query(
        arrays["points"])
    assert np.abs(arrays["points"] - vertices[nearest]).max() < 1e-6
    assert np.abs(arrays["template_weights"] - layer.skinning_weights.numpy()[nearest]).max() \
        < 1e-6


def test_point_cloud_without_normals_is_skipped(tmp_path):
    folder = tmp_path / "scans"
    folder.mkdir()
    rng = np.random.default_rng(0)
    points = 0.05 * rng.standard_normal((50, 3))
    header = ("ply\nformat ascii 1.0\nelement vertex 50\nproperty float x\nproperty float y\n"
              "property float z\nend_header\n")
    (folder / "c.ply").write_text(header + "\n".join(" ".join(map(str, p)) for p in points)
                                  + "\n")
    (folder / "c.keypoints3d.json").write_text(json.dumps({"keypoints": points[:21].tolist()}))
    with pytest.raises(ValueError, match="no frame could be imported"):
        import_scans(ScanImportConfig(root=str(folder), units="m"), tmp_path / "D",
                     progress=False)
    assert not (tmp_path / "D" / "dataset.json").exists()


def test_a_scan_without_annotations_gets_its_pose_from_the_pose_search(tmp_path):
    """``keypoints_fn`` (``lisa import scans --pose-search``: the point-cloud fit) is asked for
    the scans that have no keypoints or MANO file, with the scan's points in metres; its
    keypoints pose the frame. Here a stand-in returns the true keypoints."""
    template = load_template().to(dtype=F64)
    pose = sample_pose(torch.Generator().manual_seed(3), 1, global_orient=True).to(F64)
    betas = torch.zeros(1, template.num_betas, dtype=F64)
    posed = template(pose, betas, torch.tensor([[0.0, 0.1, 0.5]], dtype=F64))
    folder = tmp_path / "scans" / "bob"
    folder.mkdir(parents=True)
    save_mesh(folder / "bare.ply", Mesh(vertices=posed.vertices[0].numpy() * 1e3,
                                        faces=template.faces.numpy()))
    asked = []

    def search(points, normals, side):
        asked.append((points.shape, None if normals is None else normals.shape, side))
        assert np.abs(points).max() < 1.0  # metres, not the file's millimetres
        return posed.keypoints[0].numpy()

    out = tmp_path / "DATA"
    report = import_scans(ScanImportConfig(root=str(tmp_path / "scans"), num_points=2000,
                                           num_sdf_samples=500, side="right"), out,
                          progress=False, keypoints_fn=search)
    assert report.num_frames == 1 and not report.skipped
    assert asked == [((20000, 3), (20000, 3), "right")]
    params = json.loads((out / "s000" / "f000" / "params.json").read_text())
    # The frame's keypoints are the search's, to the IK's accuracy (1 mm).
    error = np.linalg.norm(np.asarray(params["keypoints"]) - posed.keypoints[0].numpy(), axis=1)
    assert error.max() < 1e-3

    def broken(points, normals, side):
        return np.zeros((5, 3))

    with pytest.raises(ValueError, match="no frame could be imported"):
        import_scans(ScanImportConfig(root=str(tmp_path / "scans"), num_points=2000,
                                      num_sdf_samples=500), tmp_path / "D2", progress=False,
                     keypoints_fn=broken)
