"""What a fit writes, all or nothing: the one writer of ``lisa fit-points``, ``lisa fit-images``
and ``lisa fit-photo``.

A fit hands :func:`write_fit` the list of its files (:class:`Artefact`: a name in the folder and
how to write it); the writer stages them beside ``--out`` and swaps them in as a whole
(:mod:`.writer`). Pieces:

* :mod:`.folder`: the output folder checked before the work (:func:`check_output_folder`),
  claimed while the fit runs (``.OUT.lock``: :func:`claim_output_folder`,
  :func:`releases_output_locks`) and replaced as a whole (:func:`write_folder`; what a killed
  fit leaves is removed, :func:`remove_stale_staging`);
* :mod:`.writer`: :class:`Artefact`, the constructors of the usual files (``params.json``,
  meshes, JSON, pictures, masks, text, ``model.pt``), :func:`write_fit`, and the files of a point
  or image fit (:func:`fit_artefacts`, :func:`write_fit_outputs`: ``params.json``,
  ``mesh.ply``, ``keypoints.json``, with ``metrics.json``, ``model.pt``, ``preview.png``);
* :mod:`.records`: ``keypoints.json``'s 3D keypoints (:func:`hand_keypoints_3d`,
  :func:`keypoints_3d_record`) and JSON without NaN (:func:`json_safe`);
* :mod:`.ground_truth`: ``--gt`` read in the unit of a hand's size (:func:`read_ground_truth`),
  the four distances of ``metrics.json`` (:func:`ground_truth_metrics`), and what the point and
  image fits check before their work (:func:`prepare_fit`).

The photo fit's files (per hand, per photo: cameras, masks, overlays, the report) are artefacts
built by :mod:`lisa_hand.fitting.photo.artefacts` and written by :func:`write_fit` too.
"""

from .folder import (
    FIT_FILES,
    Allowed,
    check_output_folder,
    claim_output_folder,
    fit_file,
    lock_output_folder,
    output_lock,
    releases_output_locks,
    remove_stale_staging,
    unlock_output_folder,
    write_folder,
)
from .ground_truth import GroundTruth, ground_truth_metrics, prepare_fit, read_ground_truth
from .records import hand_keypoints_3d, json_safe, keypoints_3d_record, posed_keypoints
from .writer import (
    Artefact,
    fit_artefacts,
    image_artefact,
    json_artefact,
    mask_artefact,
    mesh_artefact,
    model_artefact,
    params_artefact,
    text_artefact,
    write_fit,
    write_fit_outputs,
)

__all__ = [
    "FIT_FILES",
    "Allowed",
    "fit_file",
    "check_output_folder",
    "claim_output_folder",
    "lock_output_folder",
    "unlock_output_folder",
    "output_lock",
    "releases_output_locks",
    "remove_stale_staging",
    "write_folder",
    "GroundTruth",
    "read_ground_truth",
    "ground_truth_metrics",
    "prepare_fit",
    "json_safe",
    "hand_keypoints_3d",
    "posed_keypoints",
    "keypoints_3d_record",
    "Artefact",
    "params_artefact",
    "mesh_artefact",
    "json_artefact",
    "image_artefact",
    "mask_artefact",
    "text_artefact",
    "model_artefact",
    "write_fit",
    "fit_artefacts",
    "write_fit_outputs",
]
