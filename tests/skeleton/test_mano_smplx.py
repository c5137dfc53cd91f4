"""Our MANO layer against smplx's (the implementation everyone uses) on the same synthetic
MANO file in the official layout: right and left, PCA and full pose, float64.

smplx reads the pickle with the plain ``pickle`` module, so the ``chumpy.ch.Ch`` object of the
official ``shapedirs`` needs a module ``chumpy``: the test gives it a minimal stand-in (the
state and ``__array__``) for the duration of the test only. smplx is a test-only dependency
(the ``test`` extra); the test skips when it is missing.
"""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import torch

from lisa_hand.skeleton import ManoLayer
from tests.skeleton.synthetic_mano import write_synthetic_mano

smplx = pytest.importorskip("smplx", reason="smplx is a test dependency: pip install smplx")

F64 = torch.float64
# smplx's Rodrigues adds 1e-8 to the rotation vector before its norm (ours is exact at zero):
# the two agree to about 1e-8 m on hands of unit-scale random poses.
SMPLX_EPSILON_TOL = 5e-8


class _Ch:
    """Stand-in for ``chumpy.ch.Ch`` while smplx unpickles: keeps the state, acts as its x."""

    def __setstate__(self, state):
        self.__dict__.update(state)

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.x, dtype=dtype)

    @property
    def shape(self):
        return np.shape(self.x)

    def __getitem__(self, key):
        return np.asarray(self.x)[key]


@pytest.fixture(scope="module")
def mano_files(tmp_path_factory):
    root = tmp_path_factory.mktemp("mano_smplx")
    write_synthetic_mano(root / "MANO_RIGHT.pkl", "right", seed=3)
    write_synthetic_mano(root / "MANO_LEFT.pkl", "left", seed=3)
    return root


@pytest.fixture
def fake_chumpy(monkeypatch):
    chumpy = types.ModuleType("chumpy")
    chumpy_ch = types.ModuleType("chumpy.ch")
    chumpy_ch.Ch = _Ch
    chumpy.ch = chumpy_ch
    monkeypatch.setitem(sys.modules, "chumpy", chumpy)
    monkeypatch.setitem(sys.modules, "chumpy.ch", chumpy_ch)


def smplx_layer(path, side: str, use_pca: bool, flat: bool = False):
    return smplx.MANO(str(path), is_rhand=side == "right", use_pca=use_pca, num_pca_comps=6,
                      flat_hand_mean=flat, dtype=F64)


def random_inputs(width: int, batch: int = 8, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return {
        "hand_pose": 0.6 * torch.randn(batch, width, generator=g, dtype=F64),
        "global_orient": torch.randn(batch, 3, generator=g, dtype=F64),
        "betas": torch.randn(batch, 10, generator=g, dtype=F64),
        "transl": 0.2 * torch.randn(batch, 3, generator=g, dtype=F64),
    }


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("use_pca", [True, False])
@pytest.mark.parametrize("flat", [False, True])
def test_vertices_and_joints_match_smplx(mano_files, fake_chumpy, side, use_pca, flat):
    path = mano_files / f"MANO_{side.upper()}.pkl"
    theirs = smplx_layer(path, side, use_pca, flat)
    ours = ManoLayer(path, use_pca=use_pca, num_pca_comps=6, flat_hand_mean=flat, dtype=F64)
    inputs = random_inputs(6 if use_pca else 45)
    expected = theirs(**inputs, return_full_pose=True)
    got = ours(**inputs)
    assert float((got.vertices - expected.vertices).abs().max()) < SMPLX_EPSILON_TOL
    assert float((got.joints - expected.joints[:, :16]).abs().max()) < SMPLX_EPSILON_TOL
    # The full pose both apply (PCA and mean hand included) is the same up to round-off.
    assert torch.allclose(got.full_pose, expected.full_pose, atol=1e-12)
    # And the shapes are far from trivial: the hands moved by centimetres.
    assert float((expected.vertices - theirs().vertices).abs().max()) > 0.05
