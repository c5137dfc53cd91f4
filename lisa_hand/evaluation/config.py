"""The settings of ``lisa eval`` (:class:`EvalConfig`): which tables, how many frames, how fine."""

from __future__ import annotations

from dataclasses import dataclass

from ..utils.config import check_int_fields

__all__ = ["VIEW_COUNTS", "EvalConfig"]

VIEW_COUNTS = (1, 2, 4)
"""The input view counts of Tables 2 and 3."""


@dataclass(frozen=True)
class EvalConfig:
    """What :func:`lisa_hand.evaluation.tables.run_eval` measures (defaults: the full run of
    ``docs/results.md``)."""

    num_subjects: int | None = None
    """Table 1 set 'subjects': held-out subjects, frame f000 each (None: all)."""
    num_poses: int = 6
    """Table 1 set 'poses': frames of one held-out subject."""
    pose_subject: str | None = None
    """The subject of set 'poses' (None: the last test subject)."""
    image_subjects: int = 4
    """Tables 2 and 3: held-out subjects (frame f000 each)."""
    views: tuple[int, ...] = VIEW_COUNTS
    """Input view counts of Tables 2 and 3 (each of 1, 2, 4)."""
    resolution: int = 256
    """Marching-cubes samples a side for every implicit method (the paper: 256)."""
    template_vertices: int = 100_000
    """The MANO-like mesh is loop-subdivided to about this many vertices (the paper: ~100k)."""
    fit_scale: float = 1.0
    """Multiplies every fit's iteration counts (quick mode: a small fraction)."""
    render_samples: int = 32
    """Samples per ray in the band around the surface for the novel views."""
    tables: tuple[str, ...] = ("points", "images")
    """Which fits to run: 'points' (Table 1) and/or 'images' (Tables 2 and 3)."""
    workers: int = 2
    """Processes running fits at once (one CPU thread each); 1: in this process."""
    device: str = "cpu"
    """Where the models run: 'cpu', 'cuda', 'cuda:N' or 'auto' (CUDA when available)."""

    def __post_init__(self) -> None:
        check_int_fields(self, ("num_poses", "image_subjects", "resolution", "workers",
                                "template_vertices", "render_samples"), 1)
        if self.num_subjects is not None and self.num_subjects < 1:
            raise ValueError(f"num_subjects must be >= 1 or None, got {self.num_subjects!r}")
        if not self.views or any(v not in VIEW_COUNTS for v in self.views):
            raise ValueError(f"views must be a non-empty subset of {VIEW_COUNTS}, got "
                             f"{self.views!r}")
        if not self.tables or any(t not in ("points", "images") for t in self.tables):
            raise ValueError(f"tables must name 'points' and/or 'images', got {self.tables!r}")
        if not self.fit_scale > 0:
            raise ValueError(f"fit_scale must be > 0, got {self.fit_scale!r}")
