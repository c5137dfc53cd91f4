"""The importers' MANO conversions against smplx, used the way each dataset's own code uses it:
InterHand2.6M (``smplx.create(..., use_pca=False)``, pose[:3] / pose[3:], shape, trans) and
FreiHAND (mean pose added, root joint on xyz[0])."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lisa_hand.data.importers.mano_params import freihand_mano, interhand_mano, load_mano_layers
from lisa_hand.skeleton import forward_kinematics
from tests.skeleton.synthetic_mano import write_synthetic_mano
from tests.skeleton.test_mano_smplx import SMPLX_EPSILON_TOL, fake_chumpy  # noqa: F401

smplx = pytest.importorskip("smplx", reason="smplx is a test dependency: pip install smplx")
F64 = torch.float64


@pytest.fixture(scope="module")
def mano_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("mano_params")
    write_synthetic_mano(root / "MANO_RIGHT.pkl", "right", seed=6)
    write_synthetic_mano(root / "MANO_LEFT.pkl", "left", seed=6)
    return root


def our_joints(layer, params):
    """Joints as the importer poses a frame: full pose on J(betas), wrist translation."""
    betas = torch.as_tensor(params.betas[None], dtype=F64)
    hand_pose = torch.as_tensor(params.hand_pose[None], dtype=F64)
    out = layer(hand_pose=hand_pose, global_orient=torch.as_tensor(params.global_orient[None]),
                betas=betas, transl=torch.as_tensor(params.transl[None]))
    rest = layer(betas=betas).rest_joints
    translation = out.joints[:, 0] - rest[:, 0]
    return forward_kinematics(out.full_pose, rest, translation).joints[0]


@pytest.mark.parametrize("side", ["right", "left"])
def test_interhand_parameters(mano_dir, fake_chumpy, side):  # noqa: F811
    rng = np.random.default_rng(1)
    entry = {"pose": (0.5 * rng.standard_normal(48)).tolist(),
             "shape": rng.standard_normal(10).tolist(), "trans": [0.1, -0.2, 0.9]}
    layer = load_mano_layers(mano_dir, fix_left_shapedirs=True)[side]
    ours = our_joints(layer, interhand_mano(entry, "test"))
    theirs = smplx.create(str(mano_dir / f"MANO_{side.upper()}.pkl"), "mano", use_pca=False,
                          is_rhand=side == "right", dtype=F64)
    # InterHand2.6M's fix of MANO_LEFT.pkl, as its code writes it.
    if side == "left" and float((theirs.shapedirs[:, 0, :] - smplx.create(
            str(mano_dir / "MANO_RIGHT.pkl"), "mano", use_pca=False, dtype=F64
    ).shapedirs[:, 0, :]).abs().sum()) < 1:
        theirs.shapedirs[:, 0, :] *= -1
    pose = torch.tensor([entry["pose"]], dtype=F64)
    expected = theirs(global_orient=pose[:, :3], hand_pose=pose[:, 3:],
                      betas=torch.tensor([entry["shape"]], dtype=F64),
                      transl=torch.tensor([entry["trans"]], dtype=F64)).joints[0, :16]
    assert float((ours - expected).abs().max()) < SMPLX_EPSILON_TOL


def test_freihand_parameters(mano_dir, fake_chumpy):  # noqa: F811
    rng = np.random.default_rng(2)
    theta = np.concatenate([0.5 * rng.standard_normal(48), rng.standard_normal(10),
                            [100.0, 110.0, 1.0]])
    root = np.array([0.02, -0.01, 0.65])
    layer = load_mano_layers(mano_dir)["right"]
    ours = our_joints(layer, freihand_mano([theta.tolist()], root, layer, "test"))
    # FreiHAND's HandModel(use_mean_pose=True) = smplx with flat_hand_mean=False, then the
    # root joint moved onto xyz[0].
    theirs = smplx.MANO(str(mano_dir / "MANO_RIGHT.pkl"), use_pca=False, flat_hand_mean=False,
                        dtype=F64)
    pose = torch.tensor(theta[None, :48], dtype=F64)
    posed = theirs(global_orient=pose[:, :3], hand_pose=pose[:, 3:],
                   betas=torch.tensor(theta[None, 48:58], dtype=F64)).joints[0, :16]
    expected = posed - posed[0] + torch.from_numpy(root)
    assert float((ours - expected).abs().max()) < SMPLX_EPSILON_TOL
