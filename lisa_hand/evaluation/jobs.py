"""The fits of ``lisa eval`` as jobs: what they are (:class:`PointJob`, :class:`ImageJob`), which
to run (:func:`plan_jobs`), running them (:func:`run_job`, :func:`run_jobs`) and keeping each
result in ``OUT/jobs/ID.json`` as it finishes, so that the same command resumes.

A job is a frozen dataclass of plain values; its :meth:`~PointJob.to_dict` is the cache key
stored beside the result (``{"job": ..., "result": ...}``): a cached result is reused only for
the very same job. The keys and values are those of the job dicts of earlier versions, so their
caches stay valid.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from ..utils.io import read_json, write_json
from ..utils.pool import run_tasks
from ..utils.threads import cpu_threads
from .config import EvalConfig
from .methods import METHODS, TEMPLATE_METHOD, FieldMethod, FitSettings, image_inputs

__all__ = ["PointJob", "ImageJob", "Job", "ModelCache", "plan_jobs", "run_job", "run_jobs",
           "cached_results"]


@dataclass(frozen=True)
class PointJob:
    """Table 1: one method fitted to one frame's scan."""

    kind: ClassVar[str] = "points"
    set: str
    """The test set: 'subjects' or 'poses'."""
    frame_name: str
    """``SUBJECT_FRAME``, e.g. ``s003_f000``."""
    method: str
    """A name of :data:`~lisa_hand.evaluation.methods.METHODS`."""
    frame: str
    """The frame folder."""
    model: str | None
    """The method's trained model (None: the mesh template)."""
    out: str
    """Folder of the fit's files."""
    settings: FitSettings
    """Resolution, iteration scale, template size, device."""

    @property
    def job_id(self) -> str:
        """File stem of the job's cached result."""
        return f"points_{self.set}_{self.frame_name}_{self.method}"

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON): the job's cache key."""
        return {"kind": self.kind, "set": self.set, "frame_name": self.frame_name,
                "method": self.method, "frame": self.frame, "model": self.model,
                "out": self.out, **dataclasses.asdict(self.settings)}


@dataclass(frozen=True)
class ImageJob:
    """Tables 2 and 3: one frame and view count, fitted by the template (stage 1) and then by
    every colour model from it."""

    kind: ClassVar[str] = "images"
    frame_name: str
    """``SUBJECT_FRAME``, e.g. ``s003_f000``."""
    num_views: int
    """Input views: 1, 2 or 4."""
    frame: str
    """The frame folder."""
    views: tuple[str, ...]
    """Camera names of the input views."""
    novel: tuple[str, ...]
    """Camera names of the novel views (never inputs)."""
    models: tuple[tuple[str, str], ...]
    """(method, model path) of every colour model, in table order."""
    render_samples: int
    """Samples per ray in the band around the surface for the novel views."""
    out: str
    """Folder of the fits' files (one subfolder per method)."""
    settings: FitSettings
    """Resolution, iteration scale, template size, device."""

    @property
    def job_id(self) -> str:
        """File stem of the job's cached result."""
        return f"images_{self.num_views}_{self.frame_name}"

    def to_dict(self) -> dict[str, Any]:
        """Plain data (JSON): the job's cache key."""
        return {"kind": self.kind, "frame_name": self.frame_name, "num_views": self.num_views,
                "frame": self.frame, "views": list(self.views), "novel": list(self.novel),
                "models": dict(self.models), "render_samples": self.render_samples,
                "out": self.out, **dataclasses.asdict(self.settings)}


Job = PointJob | ImageJob


class ModelCache:
    """The trained models of one evaluation run, each loaded once (per process) on first use.

    Created by the runner and passed to every job it runs; a job only reads the models (the
    fits optimise codes and poses of their own, never the weights).
    """

    def __init__(self) -> None:
        self._models: dict[tuple[str, str], Any] = {}

    def get(self, path: str, device: str):
        """The :class:`~lisa_hand.model.trained.TrainedModel` of ``path`` on ``device``."""
        from ..model.trained import load_trained

        key = (path, device)
        if key not in self._models:
            self._models[key] = load_trained(path, device)
        return self._models[key]


# ------------------------------------------------------------------------------------------------
# Planning


def _spread(names: Sequence[str], count: int) -> list[str]:
    step = len(names) / count
    return [names[int(i * step)] for i in range(count)]


def _test_frames(data_dir: Path) -> tuple[list[str], dict[str, list]]:
    """The test subjects that have frames, and their frames (sorted by name)."""
    from ..data.layout import list_frames, read_split

    subjects = read_split(data_dir).get("test", [])
    if not subjects:
        raise ValueError(f"{data_dir}: the split has no test subjects (split.json)")
    frames: dict[str, list] = {}
    for paths in list_frames(data_dir, subjects):
        frames.setdefault(paths.root.parent.name, []).append(paths)
    for subject in frames:
        frames[subject].sort(key=lambda p: p.root.name)
    return [s for s in subjects if s in frames], frames


def _point_jobs(data_dir: Path, subjects: list[str], frames: dict[str, list],
                models: dict[str, str], config: EvalConfig, settings: FitSettings,
                out: Path) -> list[PointJob]:
    pose_subject = config.pose_subject or subjects[-1]
    if pose_subject not in frames:
        raise ValueError(f"{data_dir}: pose subject {pose_subject!r} is not a test subject "
                         f"({', '.join(subjects)})")
    sets = {"subjects": [frames[s][0] for s in subjects[: config.num_subjects]],
            "poses": frames[pose_subject][: config.num_poses]}
    point_methods = [TEMPLATE_METHOD.name, *[m for m in models if m in METHODS]]
    jobs = []
    for set_name, paths_list in sets.items():
        for paths in paths_list:
            name = f"{paths.root.parent.name}_{paths.root.name}"
            for method in point_methods:
                jobs.append(PointJob(
                    set=set_name, frame_name=name, method=method, frame=str(paths.root),
                    model=models.get(method),
                    out=str(out / "fits" / "points" / set_name / name / method),
                    settings=settings))
    return jobs


def _image_jobs(subjects: list[str], frames: dict[str, list], models: dict[str, str],
                config: EvalConfig, settings: FitSettings, out: Path) -> list[ImageJob]:
    from ..geometry.cameras import load_cameras

    color_models = tuple((m, p) for m, p in models.items() if METHODS[m].color is True)
    jobs = []
    for subject in subjects[: config.image_subjects]:
        paths = frames[subject][0]
        names = [camera.name for camera in load_cameras(paths.cameras)]
        if len(names) < 5:
            raise ValueError(f"{paths.root}: {len(names)} views; the image tables need at "
                             "least 5 (4 inputs and a novel view)")
        inputs = _spread(names, 4)
        chosen = {1: inputs[:1], 2: [inputs[0], inputs[2]], 4: inputs}
        novel = tuple(n for n in names if n not in inputs)
        name = f"{paths.root.parent.name}_{paths.root.name}"
        for count in config.views:
            jobs.append(ImageJob(
                frame_name=name, num_views=count, frame=str(paths.root),
                views=tuple(chosen[count]), novel=novel, models=color_models,
                render_samples=config.render_samples,
                out=str(out / "fits" / f"images_{count}" / name), settings=settings))
    return jobs


def plan_jobs(data_dir: Path, models: dict[str, str], config: EvalConfig, out: Path
              ) -> list[Job]:
    """The fits to run: one job per (method, frame) for the point clouds, one per (frame, view
    count) for the images."""
    from ..utils.device import resolve_device

    subjects, frames = _test_frames(data_dir)
    settings = FitSettings(resolution=config.resolution, fit_scale=config.fit_scale,
                           template_vertices=config.template_vertices,
                           device=str(resolve_device(config.device)))
    jobs: list[Job] = []
    if "points" in config.tables:
        jobs += _point_jobs(data_dir, subjects, frames, models, config, settings, out)
    if "images" in config.tables:
        jobs += _image_jobs(subjects, frames, models, config, settings, out)
    return jobs


# ------------------------------------------------------------------------------------------------
# Running


def _run_point_job(job: PointJob) -> dict:
    """One method fitted to one frame's scan -> its row: the four distances and the time."""
    from ..data.layout import FramePaths

    metrics = METHODS[job.method].fit_points(FramePaths(Path(job.frame)), Path(job.out),
                                             job.settings, job.model)
    return {"kind": job.kind, "set": job.set, "frame_name": job.frame_name,
            "method": job.method, **metrics}


def _run_image_job(job: ImageJob, models: ModelCache) -> list[dict]:
    """Stage 1 once for the frame and view count (also the template's row), then stage 2, the
    mesh and the novel views for every colour model."""
    inputs = image_inputs(Path(job.frame), job.views, job.novel, Path(job.out), job.settings,
                          job.render_samples)
    base = {"kind": job.kind, "frame_name": job.frame_name, "num_views": job.num_views}
    row, pose_fit = TEMPLATE_METHOD.fit_images(inputs)
    stage1 = row["seconds"]
    rows = [{**base, "method": TEMPLATE_METHOD.name, **row}]
    for method, path in job.models:
        spec = METHODS[method]
        assert isinstance(spec, FieldMethod), method  # planned from the colour models only
        model = models.get(path, job.settings.device)
        rows.append({**base, "method": method,
                     **spec.fit_images(inputs, model, start=pose_fit, start_seconds=stage1)})
    return rows


def run_job(job: Job, models: ModelCache | None = None) -> dict | list[dict]:
    """Run one job -> its result (a point job: one row; an image job: one row per method).

    models: where the job's trained models are loaded from (None: a cache of its own).
    """
    if isinstance(job, PointJob):
        return _run_point_job(job)
    return _run_image_job(job, ModelCache() if models is None else models)


def cached_results(jobs: Sequence[Job], folder: Path) -> tuple[dict[str, Any], list[Job]]:
    """Results kept in ``folder`` (``ID.json``) for exactly these jobs, and the jobs to run.

    -> ({job_id: result} of the cached ones, the others in order).
    """
    done: dict[str, Any] = {}
    todo = []
    for job in jobs:
        cached = folder / f"{job.job_id}.json"
        record = read_json(cached) if cached.is_file() else None
        if record is not None and record.get("job") == job.to_dict():  # same fit, same settings
            done[job.job_id] = record["result"]
        else:
            todo.append(job)
    return done, todo


def run_jobs(jobs: Sequence[Job], workers: int, folder: Path,
             on_done: Callable[[], None] | None = None) -> dict[str, Any]:
    """Run ``jobs``, each result written to ``folder/ID.json`` as it finishes (``on_done()``
    called then); -> {job_id: result}.

    workers: 1 (or one job): in this process, one torch thread, one :class:`ModelCache` for all
    the jobs; more: that many one-thread processes (:func:`lisa_hand.utils.pool.run_tasks`),
    each job loading its own models (well under a second beside a fit's tens).
    """
    results: dict[str, Any] = {}

    def finish(job: Job, result: Any) -> None:
        write_json(folder / f"{job.job_id}.json", {"job": job.to_dict(), "result": result})
        results[job.job_id] = result
        if on_done is not None:
            on_done()

    if workers == 1 or len(jobs) <= 1:
        models = ModelCache()
        with cpu_threads(1):
            for job in jobs:
                finish(job, run_job(job, models))
    else:
        for (job,), result in run_tasks(run_job, [(job,) for job in jobs], workers):
            finish(job, result)
    return results
