"""Coarse-to-fine remeshing in the background: :class:`Remesher`.

Every change of the viewer's hand asks for a new mesh (:meth:`Remesher.request`). A worker
thread meshes the newest request with :func:`lisa_hand.inference.mesh_hand_with_stats` at a
coarse resolution first (a fraction of a second on one CPU core), hands it over, then at the
fine resolution. A newer request cancels the one in progress: the field callback checks the
request's generation before every chunk of grid points and stops the extraction, so the next
coarse mesh never waits for an outdated fine one.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from ..geometry.meshing import Mesh
from ..inference.hand_field import HandField, hand_field
from ..inference.mesh import MeshConfig, check_resolution, mesh_hand_with_stats
from ..model.trained import TrainedModel
from ..skeleton.params import HandParams

__all__ = ["RemeshConfig", "MeshUpdate", "MeshCancelled", "CancellableHandField", "Remesher"]

LEVELS = ("coarse", "fine")


@dataclass(frozen=True)
class RemeshConfig:
    """How the viewer re-meshes the hand."""

    coarse_resolution: int = 40
    """Grid samples per side of the first, fast mesh (0.2-0.3 s on one core)."""
    fine_resolution: int = 128
    """Grid samples per side of the mesh that replaces it (0: no fine mesh)."""
    padding: float = 0.04
    """Metres around the posed skeleton's box (:class:`lisa_hand.inference.MeshConfig`; the
    shipped model's flat mean hand reaches past 3 cm, and the grid would grow: a second pass)."""
    chunk_size: int = 16384
    """Most grid points per field call; a newer request stops an extraction between two."""

    def __post_init__(self) -> None:
        check_resolution(self.coarse_resolution)
        if self.fine_resolution != 0:
            check_resolution(self.fine_resolution)
        MeshConfig(padding=self.padding, chunk_size=self.chunk_size)  # checks both

    def levels(self) -> list[tuple[str, int]]:
        """[(level name, resolution)] in the order they are meshed."""
        levels = [("coarse", self.coarse_resolution)]
        if self.fine_resolution > self.coarse_resolution:
            levels.append(("fine", self.fine_resolution))
        return levels


@dataclass
class MeshUpdate:
    """One finished mesh: the request's ``generation``, its ``level`` ("coarse" / "fine"),
    ``resolution``, the ``params`` it shows, the ``mesh`` (colours and skinning weights) and
    the wall ``seconds`` it took."""

    generation: int
    level: str
    resolution: int
    params: HandParams
    mesh: Mesh
    seconds: float


class MeshCancelled(Exception):
    """An extraction stopped because a newer request came."""


@dataclass
class CancellableHandField(HandField):
    """A :class:`HandField` whose callbacks raise :class:`MeshCancelled` once ``cancelled()``
    is true (checked before every chunk of points)."""

    cancelled: Callable[[], bool] = field(default=lambda: False)

    def _check(self) -> None:
        if self.cancelled():
            raise MeshCancelled

    def sdf_fn(self):
        base = super().sdf_fn()

        def sdf(points):
            self._check()
            return base(points)

        return sdf

    def attributes(self, points, colors: bool = True, skin_weights: bool = True):
        self._check()
        return super().attributes(points, colors, skin_weights)

    @classmethod
    def of(cls, hand: HandField, cancelled: Callable[[], bool]) -> CancellableHandField:
        return cls(model=hand.model, params=hand.params, frame=hand.frame,
                   mirrored=hand.mirrored, cancelled=cancelled)


class Remesher:
    """A worker thread that meshes the newest requested hand, coarse then fine.

    model: the trained model. on_mesh: called (in the worker thread) with each
    :class:`MeshUpdate` of the newest request. on_error: called with an exception a request
    raised (default: re-raised in the worker, which then stops).
    """

    def __init__(self, model: TrainedModel, on_mesh: Callable[[MeshUpdate], None],
                 config: RemeshConfig | None = None,
                 on_error: Callable[[BaseException], None] | None = None) -> None:
        self.model = model
        self.config = RemeshConfig() if config is None else config
        self._on_mesh = on_mesh
        self._on_error = on_error
        self._condition = threading.Condition()
        self._pending: HandParams | None = None
        self._generation = 0
        self._busy = False
        self._closed = False
        self.cancelled = 0
        """How many extractions a newer request stopped."""
        self._thread = threading.Thread(target=self._run, name="lisa-view-remesher", daemon=True)
        self._thread.start()

    @property
    def generation(self) -> int:
        """The newest request's number (1 for the first)."""
        return self._generation

    def request(self, params: HandParams) -> int:
        """Mesh ``params`` (coarse, then fine), dropping any older request. -> its generation"""
        with self._condition:
            if self._closed:
                raise RuntimeError("the remesher is closed")
            self._generation += 1
            self._pending = params
            self._condition.notify_all()
            return self._generation

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until every request is meshed (or ``timeout`` seconds); -> True when idle."""
        deadline = time.monotonic() + timeout
        with self._condition:
            while self._pending is not None or self._busy:
                left = deadline - time.monotonic()
                if left <= 0 or not self._thread.is_alive():
                    return False
                self._condition.wait(left)
        return True

    def close(self) -> None:
        """Stop the worker (the extraction in progress is cancelled)."""
        with self._condition:
            self._closed = True
            self._generation += 1
            self._condition.notify_all()
        self._thread.join(timeout=10.0)

    def _next(self) -> tuple[HandParams, int] | None:
        with self._condition:
            self._busy = False
            self._condition.notify_all()
            while self._pending is None and not self._closed:
                self._condition.wait()
            if self._closed:
                return None
            params, self._pending = self._pending, None
            self._busy = True
            return params, self._generation

    def _run(self) -> None:
        while (job := self._next()) is not None:
            params, generation = job
            try:
                self._mesh_levels(params, generation)
            except MeshCancelled:
                self.cancelled += 1
            except Exception as exc:  # noqa: BLE001 - reported to the viewer, the worker lives on
                if self._on_error is None:
                    with self._condition:
                        self._busy = False
                        self._condition.notify_all()
                    raise
                self._on_error(exc)

    def _mesh_levels(self, params: HandParams, generation: int) -> None:
        def stale() -> bool:
            return self._generation != generation

        hand = CancellableHandField.of(hand_field(self.model, params), stale)
        config = MeshConfig(padding=self.config.padding, chunk_size=self.config.chunk_size)
        for level, resolution in self.config.levels():
            if stale():
                raise MeshCancelled
            result = mesh_hand_with_stats(self.model, params, resolution, config, hand=hand)
            if stale():
                raise MeshCancelled
            self._on_mesh(MeshUpdate(generation, level, resolution, params, result.mesh,
                                     result.seconds_total))

