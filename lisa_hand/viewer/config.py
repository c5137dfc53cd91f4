"""The viewer's settings: :class:`ViewerConfig` (what ``lisa view`` exposes as options)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .meshing import RemeshConfig

__all__ = ["VIEW_EXTRA_HINT", "ViewerConfig", "viser_missing"]

VIEW_EXTRA_HINT = "lisa view needs the view extra (viser): pip install -e '.[view]'"
"""The one line to print when viser is missing."""


def viser_missing() -> str | None:
    """None when viser can be imported, else :data:`VIEW_EXTRA_HINT`."""
    try:
        import viser  # noqa: F401
    except ImportError:
        return VIEW_EXTRA_HINT
    return None


@dataclass(frozen=True)
class ViewerConfig:
    """How ``lisa view`` serves the hand."""

    host: str = "127.0.0.1"
    """Address the web server listens on (0.0.0.0: every interface)."""
    port: int = 8080
    """Port of the web server (the next free one when it is taken)."""
    remesh: RemeshConfig = field(default_factory=RemeshConfig)
    """Coarse and fine mesh resolutions."""
    threads: int = 2
    """Torch CPU threads while serving (meshing)."""
    export_dir: Path = Path("lisa_view")
    """Folder the Export panel writes into (params.json, mesh.ply, view.json, screenshot.png;
    the panel's Folder box names one folder inside it, nothing is written elsewhere)."""
    export_resolution: int = 160
    """Grid samples per side of the exported mesh.ply."""
    motion_fps: float = 12.0
    """Frames per second of a playing motion (re-posed by skinning, no re-meshing)."""
    motion_frames: int = 12
    """Frames from the hand's pose to the named pose (a motion has 2 N + 1)."""

    def __post_init__(self) -> None:
        if not 0 <= int(self.port) <= 65535:
            raise ValueError(f"port must be in [0, 65535], got {self.port}")
        if self.threads < 1:
            raise ValueError(f"threads must be >= 1, got {self.threads}")
        if self.export_resolution < 8:
            raise ValueError(f"export_resolution must be >= 8, got {self.export_resolution}")
        if not self.motion_fps > 0 or self.motion_frames < 1:
            raise ValueError("motion_fps must be > 0 and motion_frames >= 1")

    def to_dict(self) -> dict:
        """JSON-ready (written beside an export as view.json)."""
        from dataclasses import asdict

        data = asdict(self)
        data["export_dir"] = str(self.export_dir)
        return data
