"""The viewer's Photo panel: drop a photo, see the fitted hand (with the [photo] extra).

The uploaded photo is written into a temporary folder and fitted in a background thread by
:func:`lisa_hand.fitting.photo.fit.fit_photo_folder` (MediaPipe finds the hand; the fit takes
some 25 s on a CPU); each fitted hand is added to the viewer's hands as ``photo NAME`` and shown
as hand A. The panel exists only when MediaPipe is installed (or a fit function is given).
"""

from __future__ import annotations

import importlib.util
import tempfile
import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .state import NamedHand

if TYPE_CHECKING:
    from .gui import Controls

__all__ = ["PhotoPanel", "photo_available", "add_photo_panel"]

_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp", ".bmp", ".tif", ".tiff", ".heic")


def photo_available() -> bool:
    """Whether the photo extra (MediaPipe) is installed (not imported: that takes seconds)."""
    return importlib.util.find_spec("mediapipe") is not None


class PhotoPanel:
    """Upload button, status line and the background fit (see the module docstring).

    fit: called as ``fit([photo], out_dir, model_path=..., progress=False, log=...)`` and
    returning reports with a ``params`` (:func:`fit_photo_folder`'s signature).
    """

    def __init__(self, controls: Controls, fit: Callable[..., Any]) -> None:
        self.controls = controls
        self.fit = fit
        self.thread: threading.Thread | None = None
        self.error: str | None = None
        self._folder = tempfile.TemporaryDirectory(prefix="lisa_view_photo_")
        gui = controls.gui
        with gui.add_folder("Photo"):
            self.upload = gui.add_upload_button("Fit a photo", mime_type="image/*",
                                                hint="A photo of one hand (JPEG or PNG)")
            self.status = gui.add_markdown("Drop a photo of a hand: it is fitted here "
                                           "(about 25 s) and shown as hand A.")
        controls.handles["photo_upload"] = self.upload
        controls.handles["photo_status"] = self.status

        @self.upload.on_upload
        def _(_event) -> None:
            self.start(self.upload.value.name, self.upload.value.content)

    def start(self, name: str, content: bytes) -> threading.Thread | None:
        """Fit the photo ``name`` (its bytes ``content``) in a background thread."""
        suffix = Path(name).suffix.lower()
        if suffix not in _IMAGE_SUFFIXES or not content:
            self.status.content = f"{name or 'upload'}: not a photo (JPEG, PNG, ...)"
            return None
        if self.thread is not None and self.thread.is_alive():
            self.status.content = "a photo is being fitted; wait for it"
            return None
        job = Path(tempfile.mkdtemp(dir=self._folder.name))
        photo = job / f"photo{suffix}"
        photo.write_bytes(content)
        self.status.content = f"fitting {name} ..."
        self.thread = threading.Thread(target=self._run, args=(name, photo, job / "fit"),
                                       daemon=True, name="lisa-view-photo")
        self.thread.start()
        return self.thread

    def _run(self, name: str, photo: Path, out_dir: Path) -> None:
        viewer = self.controls.viewer

        def log(line: str) -> None:
            self.status.content = f"{name}: {line}"

        try:
            reports = self.fit([photo], out_dir, model_path=viewer.model_path, progress=False,
                               log=log)
        except (ValueError, OSError, ImportError, RuntimeError) as exc:
            self.error = str(exc)
            self.status.content = f"{name}: fit failed: {exc}"
            return
        label = viewer.hands[0].params.model
        for number, report in enumerate(reports):
            params = replace(report.params, model=label)
            suffix = f" hand {number}" if len(reports) > 1 else ""
            viewer.add_hand(NamedHand(f"photo {Path(name).stem}{suffix}", params, "photo"))
        self.status.content = f"{name}: fitted {len(reports)} hand(s), shown as hand A"


def add_photo_panel(controls: Controls, fit: Callable[..., Any] | None = None
                    ) -> PhotoPanel | None:
    """The Photo panel, or None without the photo extra and without ``fit``."""
    if fit is None:
        if not photo_available():
            return None
        from ..fitting.photo.fit import fit_photo_folder

        fit = fit_photo_folder
    return PhotoPanel(controls, fit)
