"""``lisa view`` against hostile input (issue 48): a page of another site cannot connect (a real
websocket client), exports stay inside the export folder, and junk GUI values, set through
viser's Python API or sent by a browser, are notes on the status line, never tracebacks."""

from __future__ import annotations

import math
import time
import urllib.request
from dataclasses import replace

import pytest

from lisa_hand.viewer.export import export_folder
from lisa_hand.viewer.origin import origin_allowed
from tests.inference.helpers import PADDING, hand_params, tiny_model
from tests.viewer.conftest import free_port

viser = pytest.importorskip("viser", reason="the view extra (viser) is not installed: "
                                            "pip install -e '.[view]'")

import msgspec  # noqa: E402  (a dependency of viser)
from websockets.exceptions import InvalidStatus  # noqa: E402  (a dependency of viser)
from websockets.sync.client import connect  # noqa: E402

from lisa_hand.viewer.config import ViewerConfig  # noqa: E402
from lisa_hand.viewer.meshing import RemeshConfig  # noqa: E402
from lisa_hand.viewer.server import HandViewer  # noqa: E402
from lisa_hand.viewer.state import NamedHand  # noqa: E402

SUBPROTOCOL = f"viser-v{viser.__version__}"


pytestmark = pytest.mark.usefixtures("one_thread_per_module")  # the CPU is shared


@pytest.fixture(scope="module")
def model():
    return tiny_model()


@pytest.fixture()
def viewer(model, tmp_path):
    hands = [NamedHand(name, replace(hand_params(model, row), model="tiny"), "test")
             for row, name in ((0, "A"), (1, "B"))]
    config = ViewerConfig(port=free_port(), export_dir=tmp_path / "export",
                          export_resolution=16,
                          remesh=RemeshConfig(coarse_resolution=16, fine_resolution=0,
                                              padding=PADDING))
    viewer = HandViewer(model, hands, config)
    assert viewer.wait_idle(30.0)
    yield viewer
    viewer.close()


def _connect(viewer, origin=None):
    """A websocket to the viewer, as its browser client opens it (viser counts a client once
    its first camera message comes)."""
    socket = connect(f"ws://127.0.0.1:{viewer.port}", origin=origin, subprotocols=[SUBPROTOCOL],
                     open_timeout=10, max_queue=None)
    socket.send(msgspec.msgpack.encode({
        "type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0], "position": [0.0, 0.0, 1.0],
        "fov": 1.0, "near": 0.01, "far": 100.0, "image_height": 480, "image_width": 640,
        "look_at": [0.0, 0.0, 0.0], "up_direction": [0.0, 0.0, 1.0]}))
    return socket


def _wait(condition, timeout=10.0) -> bool:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def _no_tracebacks(capfd, caplog) -> None:
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err, out + err
    assert not [r for r in caplog.records if r.levelname in ("ERROR", "CRITICAL")]


# -- who may connect -------------------------------------------------------------------------
@pytest.mark.parametrize("origin, allowed", [
    (None, True),                          # not a web page: a local script
    ("http://127.0.0.1:8080", True),
    ("http://localhost:8080", True),
    ("HTTP://LOCALHOST:8080", True),
    ("http://[::1]:8080", True),
    ("http://192.168.1.5:8080", True),     # the address the request came in on (0.0.0.0)
    ("http://evil.example", False),
    ("http://evil.example:8080", False),   # DNS rebinding: a name resolving to this machine
    ("http://localhost:3000", False),      # another local server's page
    ("https://127.0.0.1:8080", False),
    ("http://127.0.0.1:8080.evil.example", False),
    ("http://10.0.0.9:8080", False),       # not the address it came in on
    ("null", False),                       # a sandboxed frame, a file:// page
    ("", False),
])
def test_origin_rule(origin, allowed):
    assert origin_allowed(origin, 8080, "192.168.1.5") is allowed
    assert origin_allowed("http://[::1]:8080", 8080, "::ffff:127.0.0.1")
    assert origin_allowed("http://127.0.0.1", 80) and not origin_allowed("http://127.0.0.1", 81)


def test_a_foreign_page_is_refused_and_the_own_page_connects(viewer, caplog):
    port = viewer.port
    for origin in ("http://evil.example", f"http://evil.example:{port}", "null",
                   f"http://localhost:{port + 1}"):
        with pytest.raises(InvalidStatus) as refused:
            _connect(viewer, origin)
        assert refused.value.response.status_code == 403, origin
    assert "refused a connection from 'http://evil.example'" in caplog.text
    with urllib.request.urlopen(viewer.url, timeout=10) as page:  # the page itself: served
        assert page.status == 200 and b"<html" in page.read(4096).lower()
    assert not viewer.server.get_clients()
    for origin in (f"http://127.0.0.1:{port}", f"http://localhost:{port}", None):
        with _connect(viewer, origin) as socket:
            assert socket.subprotocol == SUBPROTOCOL
            assert _wait(lambda: len(viewer.server.get_clients()) == 1), origin
        assert _wait(lambda: not viewer.server.get_clients())


# -- where exports go ------------------------------------------------------------------------
def test_export_folder_names(tmp_path):
    root = tmp_path / "root"
    assert export_folder(root, "") == root.resolve() == export_folder(root, " . ")
    assert export_folder(root, " anna 2 ") == root.resolve() / "anna 2"
    for name in ("../x", "..", str(tmp_path / "abs"), "a/b", "a\\b", "C:x", "x\x00y",
                 "line\nbreak", "n" * 101, 5):
        with pytest.raises(ValueError, match="one name inside|must be a name"):
            export_folder(root, name)  # type: ignore[arg-type]
    root.mkdir()
    (root / "link").symlink_to(tmp_path)
    with pytest.raises(ValueError, match="leads out of"):
        export_folder(root, "link")


def _files(folder):
    return sorted(str(path.relative_to(folder)) for path in folder.rglob("*"))


def test_export_writes_only_inside_the_export_folder(viewer, tmp_path):
    handles = viewer.controls.handles
    fit = tmp_path / "somewhere" / "else"
    fit.mkdir(parents=True)
    (fit / "params.json").write_text("an earlier fit")
    root = viewer.export_root
    root.mkdir(parents=True, exist_ok=True)
    (root / "out").symlink_to(tmp_path / "somewhere")
    before = _files(tmp_path)
    for name in ("../somewhere/else", "../x", str(tmp_path / "abs"), "sub/dir", "..",
                 "out", "a\\b"):
        handles["export_dir"].value = name
        handles["export"].value = True  # a click
        assert handles["export_status"].content.startswith("export refused: "), name
        handles["screenshot"].value = True
        assert handles["export_status"].content.startswith("export refused: "), name
    assert _files(tmp_path) == before
    assert (fit / "params.json").read_text() == "an earlier fit"
    handles["export_dir"].value = "anna"
    handles["export"].value = True
    assert sorted(path.name for path in (root / "anna").iterdir()) == [
        "mesh.ply", "params.json", "view.json"]


# -- what the panel takes --------------------------------------------------------------------
SLIDER_JUNK = (math.nan, math.inf, -math.inf, 1e308, -1e308)
PYTHON_JUNK = [(name, value) for name in ("rotation_x", "shape_t", "index_curl", "finger_3",
                                          "shape_pc0") for value in SLIDER_JUNK] + [
    (name, "no such option") for name in ("hand_a", "hand_b", "named_pose", "motion",
                                          "color_mode", "side")]


def test_junk_values_set_in_python_are_notes(viewer, capfd, caplog):
    handles = viewer.controls.handles
    state, values = viewer.state, {name: handles[name].value for name, _ in PYTHON_JUNK}
    for name, junk in PYTHON_JUNK:
        handles[name].value = junk
        note = viewer.controls.notes[-1]
        assert note.startswith(f"ignored {handles[name].label}: "), (name, note)
        assert handles["status"].content == note
        assert handles[name].value == values[name]  # the control went back
    assert len(viewer.controls.notes) == len(PYTHON_JUNK)
    assert viewer.state == state and viewer.color_mode == "skin"
    handles["rotation_x"].value = 30.0  # a good value still works
    assert viewer.state.pose.rotation_deg == (30.0, 0.0, 0.0)
    assert viewer.wait_idle(30.0)
    _no_tracebacks(capfd, caplog)


def test_junk_values_from_a_browser_are_notes(viewer, capfd, caplog):
    handles = viewer.controls.handles

    def update(name, updates, uuid=None):
        return msgspec.msgpack.encode({"type": "GuiUpdateMessage", "updates": updates,
                                       "uuid": uuid or handles[name]._impl.uuid})

    junk = [update("rotation_x", {"value": value}) for value in (
        "abc", None, [1, 2], {"a": 1}, True, *SLIDER_JUNK)]
    junk += [update("hand_a", {"value": value}) for value in ("nope", 3, None)]
    junk += [update("skeleton", {"value": value}) for value in ("yes", 1, None)]
    junk += [update("export_dir", {"value": value}) for value in (5, "a\nb", "x" * 2000)]
    junk += [update("export", {"value": "x"}), update("status", {"value": "x"}),
             update("rotation_x", {"min": -1e9}), update("rotation_x", {"value": 1.0, "max": 5}),
             update("hand_a", {"options": ["A", "evil"]}),
             update("export", {"update_cb": "x"}), update("export", {}),
             update(None, {"value": 1.0}, uuid="no-such-control")]
    with _connect(viewer) as socket:
        assert _wait(lambda: len(viewer.server.get_clients()) == 1)
        for message in junk:
            socket.send(message)
        socket.send(update("rotation_y", {"value": 10.0}))  # handled after all of the junk
        assert _wait(lambda: viewer.state.pose.rotation_deg == (0.0, 10.0, 0.0))
        with viewer._lock:  # set_state holds it until the new hand is drawn and requested
            pass
    assert len(viewer.controls.notes) == len(junk), list(viewer.controls.notes)
    assert all(note.startswith("ignored a change from a browser: ")
               for note in viewer.controls.notes)
    assert (handles["rotation_x"].min, handles["rotation_x"].max) == (-180.0, 180.0)
    assert handles["hand_a"].options == ("A", "B")
    assert handles["export_dir"].value == "" and not handles["skeleton"].value
    assert not viewer.export_root.exists()  # the Export button was never pressed
    assert viewer.wait_idle(30.0)
    _no_tracebacks(capfd, caplog)
