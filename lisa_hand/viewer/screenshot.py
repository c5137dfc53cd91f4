"""The browser check of ``lisa view``: serve a hand, load the page in headless Chromium (Debian
package ``chromium``; WebGL in software, SwiftShader), and check that the canvas shows the hand.

Chromium is driven over its DevTools protocol (:class:`ChromiumPage`: the ``websockets``
client that viser brings), so the check waits only as long as the page needs: it photographs
the page with the hand hidden until two pictures agree (the page is drawn), shows the hand,
and photographs again until the middle of the page changes. The hand is there when enough
pixels of the middle of the page differ from the hand-less picture
(:func:`middle_difference`) and from the page's background (:func:`middle_coverage`).

``python -m lisa_hand.viewer.screenshot [PARAMS ...] --out docs/viewer.png`` (the README's
picture; without PARAMS, the model's mean hand). The tests call :func:`serve_and_screenshot`
on a tiny model and skip when :func:`find_chromium` finds no browser.
"""

from __future__ import annotations

import argparse
import base64
import json
import logging
import os
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["CHROMIUM_NAMES", "find_chromium", "ChromiumPage", "middle_coverage",
           "middle_difference", "ScreenshotCheck", "serve_and_screenshot", "main"]

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
_TOLERANCE = 40
"""Summed |RGB| difference above which two pixels differ."""
_HIDE_NOTICES = ("document.querySelectorAll('.mantine-Notification-root, "
                 ".mantine-Notifications-root').forEach(e => e.remove())")
"""Removes viser's notices (e.g. 'Software WebGL rendering detected') from the page."""


def find_chromium() -> str | None:
    """Path of a Chromium / Chrome executable on PATH (``$CHROMIUM`` first), or None."""
    for name in (os.environ.get("CHROMIUM", ""), *CHROMIUM_NAMES):
        found = shutil.which(name) if name else None
        if found:
            return found
    return None


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


class ChromiumPage:
    """A headless Chromium showing ``url`` in a window of ``size`` (width, height pixels),
    driven over the DevTools protocol. RuntimeError when Chromium is missing or does not
    answer within ``timeout_s``. Use as a context manager (the browser is killed at the end)."""

    def __init__(self, url: str, size: tuple[int, int] = (1280, 800),
                 chromium: str | None = None, timeout_s: float = 30.0) -> None:
        chromium = chromium or find_chromium()
        if chromium is None:
            raise RuntimeError("no Chromium found (apt-get install chromium, or set $CHROMIUM)")
        port = _free_port()
        self._profile = tempfile.TemporaryDirectory(prefix="lisa_chromium_")
        self._process = subprocess.Popen(
            [chromium, "--headless", "--no-sandbox", "--disable-gpu-sandbox",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--hide-scrollbars",
             "--no-first-run", f"--user-data-dir={self._profile.name}",
             f"--window-size={size[0]},{size[1]}", f"--remote-debugging-port={port}",
             "--remote-allow-origins=*", url],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self._next_id = 0
        self._socket = None
        try:
            self._socket = self._connect(port, timeout_s)
            self.call("Emulation.setDeviceMetricsOverride", width=int(size[0]),
                      height=int(size[1]), deviceScaleFactor=1, mobile=False)
        except BaseException:
            self.close()
            raise

    def _connect(self, port: int, timeout_s: float):
        from websockets.sync.client import connect

        deadline = time.monotonic() + timeout_s
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list",
                                            timeout=2.0) as answer:
                    pages = [t for t in json.load(answer) if t.get("type") == "page"]
                if pages:
                    return connect(pages[0]["webSocketDebuggerUrl"], max_size=2**28,
                                   open_timeout=timeout_s)
            except OSError:
                pass
            if time.monotonic() > deadline or self._process.poll() is not None:
                raise RuntimeError(f"chromium did not start its DevTools on port {port}")
            time.sleep(0.1)

    def call(self, method: str, timeout_s: float = 60.0, **params) -> dict:
        """Send one DevTools command; -> its result (RuntimeError on an error answer)."""
        self._next_id += 1
        ident = self._next_id
        self._socket.send(json.dumps({"id": ident, "method": method, "params": params}))
        deadline = time.monotonic() + timeout_s
        while True:
            message = json.loads(self._socket.recv(timeout=max(0.1, deadline - time.monotonic())))
            if message.get("id") == ident:
                if "error" in message:
                    raise RuntimeError(f"chromium: {method}: {message['error']}")
                return message.get("result", {})

    def capture(self) -> np.ndarray:
        """The page now: [H, W, 3] uint8."""
        import imageio.v3 as iio

        data = self.call("Page.captureScreenshot", format="png")["data"]
        return np.asarray(iio.imread(base64.b64decode(data)))[..., :3]

    def wait_for(self, done: Callable[[np.ndarray], bool], timeout_s: float = 60.0,
                 interval_s: float = 0.25) -> np.ndarray:
        """Capture until ``done(picture)`` (or ``timeout_s``); -> the last picture."""
        deadline = time.monotonic() + timeout_s
        while True:
            picture = self.capture()
            if done(picture) or time.monotonic() > deadline:
                return picture
            time.sleep(interval_s)

    def close(self) -> None:
        """Close the browser (politely, then by force) and remove its profile."""
        if self._socket is not None:
            try:
                self.call("Browser.close", timeout_s=5.0)
            except Exception:  # noqa: BLE001 - it may be gone already
                pass
            self._socket.close()
            self._socket = None
        try:
            self._process.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait(timeout=10.0)
        self._profile.cleanup()

    def __enter__(self) -> ChromiumPage:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _middle(image: np.ndarray, fraction: float) -> np.ndarray:
    rgb = np.asarray(image)[..., :3].astype(np.int32)
    height, width = rgb.shape[:2]
    half_h, half_w = int(height * fraction / 2), int(width * fraction / 2)
    return rgb[height // 2 - half_h : height // 2 + half_h,
               width // 2 - half_w : width // 2 + half_w]


def middle_coverage(image: np.ndarray, fraction: float = 0.3) -> float:
    """Share of the pixels in the middle ``fraction`` x ``fraction`` of the page that differ
    from its background (the colour near its bottom-right corner) -> in [0, 1].
    image: [H, W, 3|4] uint8."""
    background = np.asarray(image)[-3, -3, :3].astype(np.int32)
    return float((np.abs(_middle(image, fraction) - background).sum(-1) > _TOLERANCE).mean())


def middle_difference(image: np.ndarray, reference: np.ndarray, fraction: float = 0.3
                      ) -> float:
    """Share of the pixels in the middle of the page that differ between ``image`` and
    ``reference`` (both [H, W, 3|4] uint8, same size) -> in [0, 1]."""
    if np.shape(image)[:2] != np.shape(reference)[:2]:
        return 1.0
    change = np.abs(_middle(image, fraction) - _middle(reference, fraction)).sum(-1)
    return float((change > _TOLERANCE).mean())


@dataclass
class ScreenshotCheck:
    """What :func:`serve_and_screenshot` saw: the PNG ``path``; ``difference``: the share of
    the middle of the page that the hand changed (:func:`middle_difference`); ``coverage``: the
    share unlike the background (:func:`middle_coverage`); the viewer's ``status`` line;
    ``seconds`` from starting Chromium to the picture."""

    path: Path
    difference: float
    coverage: float
    status: str
    seconds: float


def serve_and_screenshot(viewer_factory, path: str | os.PathLike,
                         size: tuple[int, int] = (1280, 800), timeout_s: float = 90.0,
                         min_difference: float = 0.05,
                         on_shown: Callable[[object], None] | None = None) -> ScreenshotCheck:
    """Start a viewer (``viewer_factory()`` -> :class:`~.server.HandViewer`), photograph its
    page without and with the hand (see the module docstring), write the picture with the hand
    to ``path`` (PNG), stop the viewer. ``on_shown(viewer)`` is called while the browser still
    shows the hand (e.g. to press the panel's Screenshot button)."""
    from .export import write_screenshot

    # A browser that goes away leaves half-open sockets whose handshake errors the websocket
    # server would log with a traceback: not the viewer's problem.
    quiet = logging.getLogger("websockets.server")
    level, quiet.level = quiet.level, logging.CRITICAL
    viewer = viewer_factory()
    start = time.monotonic()
    try:
        viewer.wait_idle(timeout=timeout_s)
        viewer.set_hand_visible(False)
        with ChromiumPage(viewer.url, size) as page:
            previous: list[np.ndarray] = []

            def settled(picture: np.ndarray) -> bool:
                same = bool(previous) and middle_difference(picture, previous[-1]) == 0.0
                previous.append(picture)
                return same and middle_coverage(picture, 1.0) > 0.01  # the panel is drawn

            empty = page.wait_for(settled, timeout_s)
            viewer.set_hand_visible(True)
            page.wait_for(lambda p: middle_difference(p, empty) > min_difference, timeout_s)
            page.call("Runtime.evaluate", expression=_HIDE_NOTICES)
            picture = page.capture()
            if on_shown is not None:
                on_shown(viewer)
        status = viewer.status
    finally:
        viewer.close()
        quiet.setLevel(level)
    shot = write_screenshot(path, picture)
    return ScreenshotCheck(path=shot, difference=middle_difference(picture, empty),
                           coverage=middle_coverage(picture), status=status,
                           seconds=time.monotonic() - start)


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m lisa_hand.viewer.screenshot [PARAMS ...] --out PNG``."""
    parser = argparse.ArgumentParser(prog="python -m lisa_hand.viewer.screenshot",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("params", nargs="*", help="params.json files (none: the mean hand)")
    parser.add_argument("--out", required=True, help="the PNG to write")
    parser.add_argument("--model", default=None, help="trained model (default: shipped)")
    parser.add_argument("--size", default="1280x800", help="WIDTHxHEIGHT pixels")
    parser.add_argument("--colors", default="skin", help="skin, skinning weights or normals")
    parser.add_argument("--named-pose", default=None, help="e.g. relaxed, point, ok")
    args = parser.parse_args(argv)

    from dataclasses import replace

    from ..model.trained import load_trained, model_label
    from ..skeleton.params import read_params
    from .config import ViewerConfig
    from .server import HandViewer
    from .state import NamedHand, model_hands

    model = load_trained(args.model)
    label = model_label(args.model)
    hands = [NamedHand(Path(p).stem, replace(read_params(p), model=label)) for p in args.params]
    width, height = (int(v) for v in args.size.lower().split("x"))

    def factory():
        viewer = HandViewer(model, hands + model_hands(model, label),
                            ViewerConfig(port=_free_port()), model_path=args.model)
        viewer.controls.handles["color_mode"].value = args.colors
        if args.named_pose:
            viewer.controls.handles["named_pose"].value = args.named_pose
        return viewer

    check = serve_and_screenshot(factory, args.out, (width, height))
    print(f"wrote {check.path} in {check.seconds:.1f} s: the hand changed "
          f"{check.difference:.1%} of the middle of the page ({check.coverage:.1%} unlike the "
          f"background; {check.status})")
    if check.difference < 0.05:
        raise SystemExit("the canvas does not show the hand (the middle of the page did not "
                         "change when it was shown)")


if __name__ == "__main__":
    main()
