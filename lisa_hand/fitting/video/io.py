"""A clip in, files out: :func:`fit_video_folder` (``lisa fit-video``): the output folder
checked and claimed before any work, the fit (:func:`lisa_hand.fitting.video.fit.fit_video`),
its files (:mod:`lisa_hand.fitting.video.artefacts`) written all or nothing."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..outputs import releases_output_locks
from .config import FitVideoConfig

__all__ = ["VideoFitReport", "fit_video_folder"]


@dataclass
class VideoFitReport:
    """fit: the :class:`lisa_hand.fitting.video.fit.VideoFit`. folder: the output folder.
    written: the files. metrics: ``metrics.json``'s record. seconds: the whole run (reading,
    detection, fit, files); frames_per_second: frames of the clip over it."""

    fit: Any
    folder: Path
    written: list[Path] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def frames_per_second(self) -> float:
        return len(self.fit.indices) / max(self.seconds, 1e-9)


@releases_output_locks
def fit_video_folder(video: Any, out_dir: Any, *, progress: bool = True,
                     log: Callable[[str], None] | None = print,
                     config: FitVideoConfig | None = None, **options: Any) -> VideoFitReport:
    """Fit the hands of the clip ``video`` and write the files into ``out_dir``.

    options: :func:`lisa_hand.fitting.video.fit.fit_video`'s keywords (camera_json, focal_px,
    fov_deg, side, start_s, end_s, stride, fps, model_path, device). -> the report.
    """
    from ...utils.threads import cpu_threads
    from ..outputs import claim_output_folder, write_fit
    from .artefacts import VIDEO_DESCRIBED, video_artefacts, video_entry
    from .fit import fit_video
    from .report import video_metrics

    began = time.perf_counter()
    log = log or (lambda line: None)
    config = FitVideoConfig() if config is None else config
    out_dir = claim_output_folder(out_dir, video_entry, VIDEO_DESCRIBED)
    fit = fit_video(video, progress=progress, log=log, config=config, **options)
    model = fit.model
    with cpu_threads(config.num_threads):
        metrics = video_metrics(fit, time.perf_counter() - began)
        written = write_fit(out_dir, video_artefacts(fit, model, config, metrics, progress),
                            video_entry, VIDEO_DESCRIBED)
    seconds = time.perf_counter() - began
    for note in fit.notes:
        log(note)
    return VideoFitReport(fit=fit, folder=out_dir, written=written, metrics=metrics,
                          seconds=seconds)
