"""MANO parameters as the datasets store them, in smplx's convention, and the user's MANO model.

* InterHand2.6M (``InterHand2.6M_{split}_MANO_NeuralAnnot.json``): per capture, frame and hand
  ``{"pose": [48], "shape": [10], "trans": [3]}``; the dataset's own code poses them with
  ``smplx.create(..., 'mano', use_pca=False)`` (so ``flat_hand_mean=False``) as
  ``global_orient = pose[:3]``, ``hand_pose = pose[3:]``, ``betas = shape``, ``transl = trans``,
  in metres in the world frame (it multiplies the vertices by 1000 to reach the joints' mm);
  for the left hand it first negates ``shapedirs[:, 0, :]`` of ``MANO_LEFT.pkl`` (the file's
  known quirk), so the importer loads the left model with ``fix_left_shapedirs=True``.
* FreiHAND (``training_mano.json``): per sample ``[[61]]`` = pose [48] (global orientation and
  finger pose, the mean hand added: ``use_mean_pose=True``), shape [10], then the 2D root and a
  scale of a weak-perspective model (not a translation): the translation is the one that puts
  the root joint (the wrist) on the sample's ``xyz[0]``, in metres in the camera frame.

MANO's kinematic tree and pose vector are the package's own (:mod:`lisa_hand.skeleton`), so the
full pose ``cat(global_orient, hand_pose + mean)`` is the pose of our skeleton with
``rest_joints = J(betas)`` (tested against smplx in ``tests/data/importers``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...skeleton.mano import ManoLayer
from .common import ManoParams, SkipFrame

__all__ = ["interhand_mano", "freihand_mano", "load_mano_layers"]


def _vector(value: Any, size: int, where: str, key: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        array = np.zeros(0)
    if array.size != size or not np.isfinite(array).all():
        raise SkipFrame(f"{where}: MANO {key!r} must be {size} finite numbers", "bad MANO")
    return array


def interhand_mano(entry: Any, where: str) -> ManoParams:
    """An InterHand2.6M MANO entry ``{"pose", "shape", "trans"}`` -> :class:`ManoParams`.

    where: the file and frame, for the message of a malformed entry (:class:`SkipFrame`).
    """
    if not isinstance(entry, dict) or any(k not in entry for k in ("pose", "shape", "trans")):
        raise SkipFrame(f"{where}: MANO entry must have 'pose', 'shape' and 'trans'", "bad MANO")
    pose = _vector(entry["pose"], 48, where, "pose")
    return ManoParams(global_orient=pose[:3], hand_pose=pose[3:],
                      betas=_vector(entry["shape"], 10, where, "shape"),
                      transl=_vector(entry["trans"], 3, where, "trans"), flat_hand_mean=False)


def freihand_mano(theta: Any, root_m: np.ndarray, layer: ManoLayer | None, where: str
                  ) -> ManoParams:
    """A FreiHAND MANO vector [61] (or [[61]]) -> :class:`ManoParams`.

    root_m: [3] the sample's wrist (``xyz[0]``), metres, camera frame: the translation puts
    MANO's root joint there (needs ``layer``, the user's right MANO; zero without one).
    """
    values = _vector(theta, 61, where, "parameters")
    pose, betas = values[:48], values[48:58]
    transl = np.zeros(3)
    if layer is not None:
        rest = layer(betas=torch.as_tensor(betas[None], dtype=layer.dtype)).rest_joints[0]
        transl = np.asarray(root_m, np.float64) - rest[0].double().numpy()
    return ManoParams(global_orient=pose[:3], hand_pose=pose[3:], betas=betas, transl=transl,
                      flat_hand_mean=False)


def load_mano_layers(mano_dir: str | os.PathLike | None, *, fix_left_shapedirs: bool = False
                     ) -> dict[str, ManoLayer] | None:
    """The user's MANO models of a folder (``MANO_RIGHT.pkl`` and/or ``MANO_LEFT.pkl``, the
    official files from https://mano.is.tue.mpg.de) as float64 layers with ``use_pca=False``
    and ``flat_hand_mean=False``; None for None. FileNotFoundError when neither file is there.

    fix_left_shapedirs: negate the left model's ``shapedirs[:, 0, :]``
    (:func:`lisa_hand.skeleton.load_mano_pkl`), as InterHand2.6M's own code does before posing
    its left-hand fits.
    """
    if mano_dir is None:
        return None
    folder = Path(mano_dir)
    layers = {}
    for side in ("right", "left"):
        path = folder / f"MANO_{side.upper()}.pkl"
        if path.is_file():
            layers[side] = ManoLayer(path, side, use_pca=False, flat_hand_mean=False,
                                     fix_left_shapedirs=fix_left_shapedirs,
                                     dtype=torch.float64)
    if not layers:
        raise FileNotFoundError(f"{folder}: no MANO_RIGHT.pkl or MANO_LEFT.pkl here (--mano is "
                                "the folder of the official MANO model files)")
    return layers
