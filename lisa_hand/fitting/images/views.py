"""The input of the image fit: calibrated views (:class:`ImageView`), read from a frame folder
(:func:`read_views`), and what the fit compares them with.

A frame folder is in the layout of :mod:`lisa_hand.data.layout`: ``cameras.json`` and
``images/NAME.png`` are required; ``masks/NAME.png`` and ``keypoints.json`` (21 keypoints per
view, OpenPose order, pixels; :mod:`lisa_hand.data.keypoints`) are optional.

Fallbacks for incomplete input (documented behaviour, not errors; :func:`input_notes` says
which apply):

* no ``keypoints.json`` (or a view missing from it): the pose comes from the masks alone
  (silhouette terms, with the same restarts); the keypoint loss is left out where there are no
  keypoints.
* a view without a mask: its rays are drawn from the box around the projected template (after
  the keypoint stage, plus a margin), its background colour is the median of the image border
  (:func:`background_colour`), and it has no silhouette or mask term.
* a view with neither: kept for the colour loss only. At least one view must have keypoints or
  a mask (else ValueError).
* keypoints marked visible that lie far outside the image (more than :data:`KEYPOINT_MARGIN` of
  its width or height beyond its border; a detector's or an annotation's mistake) are not
  visible: they are dropped and listed in :attr:`ImageView.dropped_keypoints`.

Pixels outside a view's mask are background: black, as in the training images
(:func:`fit_target`; an image that is black outside its mask already is used as it is, soft
edges included).

LISA and the template are right hands: a left hand is fitted as the right hand of the mirrored
views (:func:`mirror_view`) and mirrored back (:func:`lisa_hand.fitting.sides.mirror_hand`).
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from ...data.keypoints import read_keypoints
from ...data.layout import FramePaths, read_image, read_mask
from ...geometry.cameras import Camera, load_cameras
from ...skeleton import KEYPOINT_NAMES, NUM_KEYPOINTS

__all__ = [
    "KEYPOINT_MARGIN",
    "ImageView",
    "keypoints_outside",
    "read_views",
    "check_views",
    "check_moments",
    "input_notes",
    "fit_target",
    "background_colour",
    "mirror_view",
]

KEYPOINT_MARGIN = 0.1
"""A visible keypoint further outside the image than this fraction of its width (left, right)
or height (top, bottom) is dropped (:func:`keypoints_outside`)."""
_BORDER_PX = 2  # width of the image border used to estimate a view's background colour


@dataclass(eq=False)
class ImageView:
    """One calibrated view of the hand.

    name: the camera's name (``images/NAME.png``).
    camera: its calibration (OpenCV convention, :class:`lisa_hand.geometry.cameras.Camera`).
    rgb: [H, W, 3] float32 in [0, 1].
    mask: [H, W] bool foreground (other dtypes: nonzero is foreground), or None (no mask: see
        the module docstring's fallbacks).
    keypoints: [21, 2] pixels (continuous coordinates, OpenPose order), or None.
    visible: [21] bool, which keypoints count (None with ``keypoints`` None). Keypoints marked
        visible but outside the image (:func:`keypoints_outside`) are made not visible.
    dropped_keypoints: names of the keypoints that were marked visible but lie outside the image
        (filled by the constructor; kept by :meth:`to` and :func:`mirror_view`).
    landmarks_3d: [21, 3] metres, a detector's 3D landmarks of the hand in this camera's axes
        (:attr:`lisa_hand.data.detect.DetectedHand.landmarks_3d`: only their bones' directions
        count), or None.
    """

    name: str
    camera: Camera
    rgb: torch.Tensor
    mask: torch.Tensor | None = None
    keypoints: torch.Tensor | None = None
    visible: torch.Tensor | None = None
    dropped_keypoints: tuple[str, ...] = ()
    landmarks_3d: torch.Tensor | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.camera, Camera):
            raise TypeError(f"view {self.name!r}: camera must be a Camera, got "
                            f"{type(self.camera).__name__}")
        expected = (self.camera.height, self.camera.width)
        if not isinstance(self.rgb, torch.Tensor) or self.rgb.shape != expected + (3,):
            raise ValueError(f"view {self.name!r}: rgb must be [H, W, 3] = "
                             f"{list(expected) + [3]} (the camera's size), got "
                             f"{list(getattr(self.rgb, 'shape', []))}")
        if not self.rgb.is_floating_point():
            raise TypeError(f"view {self.name!r}: rgb must be floats in [0, 1], got "
                            f"{self.rgb.dtype}")
        if self.mask is not None and (not isinstance(self.mask, torch.Tensor)
                                      or self.mask.shape != expected):
            raise ValueError(f"view {self.name!r}: mask must be [H, W] = {list(expected)}, got "
                             f"{list(getattr(self.mask, 'shape', []))}")
        if self.mask is not None and self.mask.dtype != torch.bool:
            self.mask = self.mask > 0  # any nonzero value is foreground
        self.dropped_keypoints = tuple(self.dropped_keypoints)
        if self.landmarks_3d is not None and (
                not isinstance(self.landmarks_3d, torch.Tensor)
                or self.landmarks_3d.shape != (NUM_KEYPOINTS, 3)
                or not bool(torch.isfinite(self.landmarks_3d).all())):
            raise ValueError(f"view {self.name!r}: landmarks_3d must be [21, 3] finite, got "
                             f"{list(getattr(self.landmarks_3d, 'shape', []))}")
        if self.keypoints is not None:
            self._check_keypoints()

    def _check_keypoints(self) -> None:
        """Shapes of ``keypoints`` and ``visible``; drop the visible ones outside the image."""
        if self.keypoints.shape != (NUM_KEYPOINTS, 2):
            raise ValueError(f"view {self.name!r}: keypoints must be [21, 2], got "
                             f"{list(self.keypoints.shape)}")
        if self.visible is None:
            self.visible = torch.ones(NUM_KEYPOINTS, dtype=torch.bool,
                                      device=self.keypoints.device)
        elif self.visible.shape != (NUM_KEYPOINTS,):
            raise ValueError(f"view {self.name!r}: visible must be [21], got "
                             f"{list(self.visible.shape)}")
        outside = self.visible & keypoints_outside(self.keypoints, self.width, self.height)
        if bool(outside.any()):
            self.visible = self.visible & ~outside
            self.dropped_keypoints += tuple(KEYPOINT_NAMES[index]
                                            for index in outside.nonzero()[:, 0].tolist())

    @property
    def height(self) -> int:
        return self.camera.height

    @property
    def width(self) -> int:
        return self.camera.width

    @property
    def has_keypoints(self) -> bool:
        return self.keypoints is not None and bool(self.visible.any())

    def to(self, device: torch.device | str) -> ImageView:
        """This view with every tensor on ``device`` (float32 camera)."""
        def move(value: torch.Tensor | None) -> torch.Tensor | None:
            return None if value is None else value.to(device)

        return ImageView(name=self.name, camera=self.camera.to(device, torch.float32),
                         rgb=self.rgb.to(device), mask=move(self.mask),
                         keypoints=move(self.keypoints), visible=move(self.visible),
                         dropped_keypoints=self.dropped_keypoints,
                         landmarks_3d=move(self.landmarks_3d))


def keypoints_outside(keypoints: torch.Tensor, width: int, height: int,
                      margin: float = KEYPOINT_MARGIN) -> torch.Tensor:
    """Which keypoints lie outside the image beyond ``margin`` (a fraction of its width for
    ``u``, of its height for ``v``): keypoints [K, 2] pixels -> [K] bool (NaN counts as inside:
    :func:`lisa_hand.data.keypoints.read_keypoints` refuses non-finite visible keypoints)."""
    low = keypoints.new_tensor([-margin * width, -margin * height])
    high = keypoints.new_tensor([(1.0 + margin) * width, (1.0 + margin) * height])
    return ((keypoints < low) | (keypoints > high)).any(dim=-1)


def _read_cameras(paths: FramePaths) -> dict[str, Camera]:
    """``cameras.json`` -> {name: camera} in the file's order (errors name the file)."""
    if paths.cameras.is_dir():
        raise IsADirectoryError(f"{paths.cameras}: is a directory, expected a file (the views' "
                                "calibration: a list of {name, K, R, t, width, height})")
    if not paths.cameras.is_file():
        raise FileNotFoundError(f"{paths.cameras}: no such file (the views' calibration: a "
                                "list of {name, K, R, t, width, height})")
    cameras = load_cameras(paths.cameras)
    if not cameras:
        raise ValueError(f"{paths.cameras}: no cameras")
    by_name: dict[str, Camera] = {}
    for index, camera in enumerate(cameras):
        if not camera.name:
            raise ValueError(f"{paths.cameras}: camera {index} has no name (its image is "
                             "images/NAME.png)")
        if (camera.name in (".", "..") or Path(camera.name).name != camera.name
                or "\\" in camera.name or "\0" in camera.name):
            raise ValueError(f"{paths.cameras}: camera {index} is named {camera.name!r}, which "
                             "is not a plain file name (its image is images/NAME.png, inside "
                             "the frame folder)")
        if camera.name in by_name:
            raise ValueError(f"{paths.cameras}: camera name {camera.name!r} appears twice")
        by_name[camera.name] = camera
    return by_name


def _select(paths: FramePaths, cameras: dict[str, Camera],
            names: Sequence[str] | None) -> list[str]:
    """The camera names to use: ``names`` (checked against ``cameras``) or all of them."""
    if names is None:
        return list(cameras)
    selected = [str(name) for name in names]
    if not selected:
        raise ValueError("views: the list of view names is empty")
    unknown = [name for name in selected if name not in cameras]
    if unknown:
        raise ValueError(f"{paths.cameras}: no camera named {', '.join(map(repr, unknown))}"
                         f"; cameras: {', '.join(cameras)}")
    if len(set(selected)) != len(selected):
        raise ValueError(f"views: a view is listed twice in {selected}")
    return selected


def _read_mask(paths: FramePaths, name: str, camera: Camera) -> torch.Tensor | None:
    """``masks/NAME.png`` as [H, W] bool, or None without the file."""
    mask_path = paths.mask(name)
    if mask_path.is_dir():
        raise IsADirectoryError(f"{mask_path}: is a directory, expected a mask image")
    if not mask_path.is_file():
        return None
    mask = read_mask(mask_path)
    if mask.shape != (camera.height, camera.width):
        raise ValueError(f"{mask_path}: mask is {mask.shape[1]}x{mask.shape[0]} but camera "
                         f"{name!r} in {paths.cameras} is {camera.width}x{camera.height}")
    if not mask.any():
        raise ValueError(f"{mask_path}: the mask is empty (no foreground pixel); leave this "
                         "view out with --views, or remove the mask file")
    return torch.from_numpy(mask)


def read_views(root: str | os.PathLike, names: Sequence[str] | None = None) -> list[ImageView]:
    """Read the views of a frame folder (the input of ``lisa fit-images``).

    root: a folder with ``cameras.json`` (a list of ``{name, K, R, t, width, height}``),
        ``images/NAME.png`` for every camera, and optionally ``masks/NAME.png`` and
        ``keypoints.json`` (:mod:`lisa_hand.data.keypoints`).
    names: the cameras to use (default: all, in the file's order).

    Errors (ValueError / FileNotFoundError, naming the file): a missing ``cameras.json`` or
    image, missing camera fields, unnamed or duplicate cameras, unknown names, an image or mask
    whose size differs from its camera's, an empty mask, malformed keypoints, and no view with a
    mask or keypoints at all (keypoints outside the images do not count). A missing mask or
    keypoint entry is not an error (see the module docstring's fallbacks).
    """
    root = Path(root)
    if root.is_file():
        raise NotADirectoryError(f"{root}: is a file, expected a frame folder with cameras.json "
                                 "and images/")
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such folder (expected a frame folder with "
                                "cameras.json and images/)")
    paths = FramePaths(root)
    cameras = _read_cameras(paths)
    selected = _select(paths, cameras, names)
    keypoints = read_keypoints(paths.keypoints, selected) if paths.keypoints.is_file() else {}
    views = []
    for name in selected:
        camera = cameras[name]
        image_path = paths.image(name)
        rgb = read_image(image_path)
        if rgb.shape[:2] != (camera.height, camera.width):
            raise ValueError(f"{image_path}: image is {rgb.shape[1]}x{rgb.shape[0]} but camera "
                             f"{name!r} in {paths.cameras} is {camera.width}x{camera.height}")
        points = visible = None
        if name in keypoints:
            entry = keypoints[name]
            visible = torch.from_numpy(entry.visible)
            points = torch.as_tensor(entry.keypoints, dtype=torch.float32)
            points = torch.where(visible[:, None], points, torch.zeros(()))
        views.append(ImageView(name=name, camera=camera, rgb=torch.from_numpy(rgb),
                               mask=_read_mask(paths, name, camera), keypoints=points,
                               visible=visible))
    if not any(view.mask is not None or view.has_keypoints for view in views):
        dropped = sum(len(view.dropped_keypoints) for view in views)
        beyond = (f" ({dropped} keypoint(s) marked visible lie outside the images)"
                  if dropped else "")
        raise ValueError(f"{root}: no view has a mask (masks/NAME.png) or keypoints "
                         f"(keypoints.json){beyond}: the hand cannot be located")
    return views


def check_views(views: Sequence[ImageView]) -> list[ImageView]:
    """``views`` as a list, checked: not empty, ImageViews, at least one with a mask or
    keypoints (else ValueError / TypeError)."""
    views = list(views)
    if not views:
        raise ValueError("views is empty: at least one view is needed")
    for index, view in enumerate(views):
        if not isinstance(view, ImageView):
            raise TypeError(f"views[{index}] must be an ImageView, got {type(view).__name__}")
    if not any(view.mask is not None or view.has_keypoints for view in views):
        raise ValueError("no view has a mask or keypoints: the hand cannot be located")
    return views


def check_moments(moments: Sequence[int] | None, num_views: int) -> tuple[int, ...]:
    """The moment each of ``num_views`` views shows (None: all one moment, 0), checked: one
    integer a view, every moment from 0 to the largest shown (else ValueError).

    Views of one moment show the hand in one pose; views of several moments (a video's
    keyframes) show it in several poses, with one shape, skeleton and colour."""
    if moments is None:
        return (0,) * num_views
    moments = tuple(moments)
    if len(moments) != num_views:
        raise ValueError(f"moments has {len(moments)} entries for {num_views} views")
    if any(isinstance(m, bool) or not isinstance(m, numbers.Integral) or m < 0
           for m in moments):
        raise ValueError(f"moments must be integers >= 0, got {list(moments)}")
    moments = tuple(int(m) for m in moments)
    missing = sorted(set(range(max(moments) + 1)) - set(moments))
    if missing:
        raise ValueError(f"moments {missing} have no view: number the moments 0, 1, 2...")
    return moments


def input_notes(views: Sequence[ImageView]) -> list[str]:
    """One sentence per fallback the views will use (see the module docstring)."""
    notes = []
    for view in views:
        if view.dropped_keypoints:
            notes.append(f"view {view.name}: {len(view.dropped_keypoints)} keypoint(s) marked "
                         f"visible lie more than {KEYPOINT_MARGIN:.0%} of the image size "
                         f"outside it and are left out ({', '.join(view.dropped_keypoints)})")
    no_mask = [view.name for view in views if view.mask is None]
    no_keypoints = [view.name for view in views if not view.has_keypoints]
    if no_keypoints and len(no_keypoints) == len(views):
        notes.append("no keypoints: the pose comes from the masks alone (restarts over "
                     "rotations); expect a less reliable fit, above all with one view")
    elif no_keypoints:
        notes.append(f"no keypoints for view(s) {', '.join(no_keypoints)}: their masks and "
                     "colours are used")
    if no_mask:
        notes.append(f"no mask for view(s) {', '.join(no_mask)}: their rays cover the box "
                     "around the projected hand and their background colour is the image "
                     "border's median")
    return notes


def _black_outside(view: ImageView) -> bool:
    """Whether the image is already black outside its mask (beyond a 2-pixel margin: the
    synthetic images and LISA's training images): then it is used as it is, soft edges
    included."""
    from scipy.ndimage import binary_dilation

    if view.mask is None:
        return False
    grown = binary_dilation(view.mask.cpu().numpy(), iterations=2)
    outside = view.rgb.cpu()[torch.from_numpy(~grown)]
    return outside.numel() == 0 or float(outside.max(dim=-1).values.quantile(0.99)) < 0.02


def fit_target(view: ImageView) -> torch.Tensor:
    """[H, W, 3] the colours the fit compares with: the image; with a mask, black outside it
    (pixels outside a mask are background, black as in the training images), unless the image
    is black there already (then its soft edges are kept)."""
    if view.mask is None or _black_outside(view):
        return view.rgb
    return view.rgb * view.mask[..., None]


def background_colour(view: ImageView) -> torch.Tensor:
    """[3] the view's background colour in [0, 1]: black with a mask (the training images'
    convention), else the median colour of the image border (2 pixels wide)."""
    if view.mask is not None:
        return view.rgb.new_zeros(3)
    border = torch.cat([view.rgb[:_BORDER_PX].reshape(-1, 3), view.rgb[-_BORDER_PX:].reshape(-1, 3),
                        view.rgb[:, :_BORDER_PX].reshape(-1, 3),
                        view.rgb[:, -_BORDER_PX:].reshape(-1, 3)])
    return border.median(dim=0).values


def mirror_view(view: ImageView) -> ImageView:
    """The view of the mirrored world (x -> -x, :func:`lisa_hand.skeleton.mirror_points`),
    where a left hand is a right one: the image, mask and keypoints flipped left-right and the
    camera ``K' = K`` with ``cx' = W - cx`` and the skew negated, ``R' = F R M``, ``t' = F t``
    (``M = F = diag(-1, 1, 1)``; ``R'`` is a rotation again). A point ``X`` seen at pixel
    ``(u, v)`` has its mirror ``M X`` seen at ``(W - u, v)``."""
    camera = view.camera
    flip = torch.diag(camera.K.new_tensor([-1.0, 1.0, 1.0]))
    intrinsics = camera.K.clone()
    intrinsics[0, 1] = -camera.K[0, 1]
    intrinsics[0, 2] = camera.width - camera.K[0, 2]
    mirrored = Camera(K=intrinsics, R=flip @ camera.R @ flip, t=flip @ camera.t,
                      width=camera.width, height=camera.height, name=camera.name)
    keypoints = None
    if view.keypoints is not None:
        keypoints = view.keypoints.clone()
        keypoints[:, 0] = torch.where(view.visible, camera.width - keypoints[:, 0],
                                      keypoints[:, 0])
    landmarks = None
    if view.landmarks_3d is not None:
        landmarks = view.landmarks_3d * view.landmarks_3d.new_tensor([-1.0, 1.0, 1.0])
    return ImageView(name=view.name, camera=mirrored, rgb=view.rgb.flip(1),
                     mask=None if view.mask is None else view.mask.flip(1),
                     keypoints=keypoints, visible=view.visible,
                     dropped_keypoints=view.dropped_keypoints, landmarks_3d=landmarks)

