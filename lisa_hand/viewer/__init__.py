"""``lisa view``: an interactive browser viewer of a hand's pose, shape and colour (viser).

One concept per module; only :mod:`.server`, :mod:`.gui` and :mod:`.photo` touch viser (the
view extra, ``pip install -e '.[view]'``), and they import it lazily, so this package imports
without it:

* :mod:`.state`: :class:`ViewState` (what the controls set) and :func:`view_params`, the pure
  function from it to the one hand state ``HandParams`` (A/B interpolation and swaps, principal
  directions of the training codes, curl / spread / thumb / named poses / 45 joint angles,
  global rotation, side);
* :mod:`.display`: colour modes (skin, skinning weights, normals), skeleton and keypoints;
* :mod:`.meshing`: :class:`Remesher`, coarse then fine meshes in a background thread, a newer
  request cancelling the one in progress;
* :mod:`.export`: params.json, mesh.ply, view.json and screenshots;
* :mod:`.server`: :class:`HandViewer` (the viser scene) and :func:`serve`; :mod:`.gui` its
  panel; :mod:`.photo` the photo upload panel (with the photo extra);
* :mod:`.screenshot`: a headless Chromium screenshot of a served hand (the browser check).
"""

from .config import VIEW_EXTRA_HINT, ViewerConfig, viser_missing
from .display import COLOR_MODES, display_colors, skeleton_segments, weight_colors
from .meshing import MeshUpdate, RemeshConfig, Remesher
from .state import (
    CodeSpaces,
    NamedHand,
    PoseEdit,
    ViewState,
    finger_angles,
    mean_hand,
    model_hands,
    view_params,
)

__all__ = [
    "VIEW_EXTRA_HINT",
    "ViewerConfig",
    "viser_missing",
    "COLOR_MODES",
    "display_colors",
    "skeleton_segments",
    "weight_colors",
    "MeshUpdate",
    "RemeshConfig",
    "Remesher",
    "CodeSpaces",
    "NamedHand",
    "PoseEdit",
    "ViewState",
    "finger_angles",
    "mean_hand",
    "model_hands",
    "view_params",
]
