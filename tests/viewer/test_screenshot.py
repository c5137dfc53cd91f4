"""The browser check (lisa_hand.viewer.screenshot): a served hand photographed by headless
Chromium shows on the canvas; skipped without viser or Chromium."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest

from lisa_hand.viewer.screenshot import find_chromium, middle_coverage, middle_difference

from .conftest import PADDING, free_port


def test_middle_coverage_counts_pixels_unlike_the_background():
    page = np.full((100, 200, 3), 255, np.uint8)
    assert middle_coverage(page) == 0.0
    page[40:60, 90:110] = (200, 150, 120)  # 20 x 20 inside the middle 30 x 60
    assert middle_coverage(page) == pytest.approx(400 / (30 * 60))
    before = np.full_like(page, 255)
    assert middle_difference(page, before) == pytest.approx(400 / (30 * 60))
    assert middle_difference(page, page) == 0.0
    page[:, :] = 10  # a dark page: the background is what the corner shows
    assert middle_coverage(page) == 0.0


def test_chromium_shows_the_hand(model, hands, tmp_path):
    pytest.importorskip("viser", reason="the view extra (viser) is not installed")
    if find_chromium() is None:
        pytest.skip("no Chromium on PATH (Debian: apt-get install chromium); the browser "
                    "check needs it")
    from lisa_hand.viewer.config import ViewerConfig
    from lisa_hand.viewer.meshing import RemeshConfig
    from lisa_hand.viewer.screenshot import serve_and_screenshot
    from lisa_hand.viewer.server import HandViewer

    config = ViewerConfig(port=free_port(), remesh=RemeshConfig(16, 32, padding=PADDING),
                          export_dir=tmp_path / "export")
    def press_screenshot(viewer) -> None:  # the panel's button: viser's render of the canvas
        viewer.controls.handles["export_dir"].value = ""  # the export folder itself
        viewer.controls.handles["screenshot"].value = True

    check = serve_and_screenshot(lambda: HandViewer(model, hands, config),
                                 tmp_path / "page.png", size=(1280, 800), timeout_s=60.0,
                                 on_shown=press_screenshot)
    assert check.path.is_file()
    # The hand changes the middle of the page (the panel floats on the right) and is not
    # the page's background.
    assert check.difference > 0.05, f"the hand changed {check.difference:.1%} of the middle"
    assert check.coverage > 0.05, f"the middle of the page is background ({check.coverage:.1%})"
    assert "fine mesh 32^3" in check.status
    rendered = iio.imread(tmp_path / "export" / "screenshot.png")
    assert rendered.shape[:2] == (720, 960)
    assert middle_coverage(rendered) > 0.05  # the canvas alone (no panel): the hand
