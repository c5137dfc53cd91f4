"""Fitting LISA to one or more calibrated views (paper Section 4.3), as stages.

:func:`fit_images` (:mod:`.fit`) composes the stages, each a public function that takes and
returns :class:`~lisa_hand.skeleton.params.HandParams` and a
:class:`~lisa_hand.fitting.stages.StageReport`:

1. :mod:`.keypoint_stage`: the template's pose from the 2D keypoints and masks, after the
   global-pose search of :mod:`.pose_search` (triangulated keypoints, candidate rotations,
   per-finger restarts);
2. :mod:`.color_stage`: pose, shape and colour codes on the LISA field, rendered with VolSDF,
   the shape code kept in the training subjects' shape space (:mod:`.shape_prior`), each
   input view's colour response fitted beside the colour code (:mod:`.calibration`);
3. :mod:`.guard`: the surface guard (connected pieces, area against the colour stage's start)
   and its fallbacks.

Helpers: :mod:`.views` (reading and checking calibrated views), :mod:`.config`
(:class:`FitImagesConfig`), :mod:`.terms` (the 2D terms shared by the stages), :mod:`.shape_prior`
(the training subjects' shape space and hand size); :mod:`.folder`
runs a fit from a frame folder to files on disk (:func:`fit_image_folder`, what
``lisa fit-images`` calls).
"""

from .config import FitImagesConfig
from .fit import FitImagesResult, fit_images
from .folder import fit_image_folder
from .guard import GuardReport, surface_guard
from .views import ImageView, read_views

__all__ = ["FitImagesConfig", "FitImagesResult", "fit_images", "fit_image_folder", "GuardReport",
           "surface_guard", "ImageView", "read_views"]
