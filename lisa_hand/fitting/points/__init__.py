"""Fitting LISA to a point cloud (paper Section 4.3), as stages.

:func:`fit_points` (:mod:`.fit`) composes the stages, each a public function that takes and
returns :class:`~lisa_hand.skeleton.params.HandParams` and a
:class:`~lisa_hand.fitting.stages.StageReport`:

1. :mod:`.global_pose` ('align'): where the hand is and which way it faces, from candidate
   orientations x finger starts on a template proxy, pruned to the best few;
2. :mod:`.proxy` ('pose'): the articulated pose on the surface proxy;
3. :mod:`.surface_stage` ('field'): pose, skeleton and shape code on the LISA field.

Helpers: :mod:`.config` (:class:`FitPointsConfig`), :mod:`.cloud` (the target cloud, its distance
grid), :mod:`.candidates` (the unknowns while a stage optimises), :mod:`.adam`, :mod:`.monitor`
(history, progress); :mod:`.io` reads point-cloud files and runs a fit from one
(:func:`fit_point_file`, what ``lisa fit-points`` calls).
"""

from .fit import FitPointsConfig, FitResult, FitStep, fit_points
from .io import fit_point_file, prepare_point_cloud, read_point_cloud

__all__ = ["FitPointsConfig", "FitResult", "FitStep", "fit_points", "fit_point_file",
           "prepare_point_cloud", "read_point_cloud"]
