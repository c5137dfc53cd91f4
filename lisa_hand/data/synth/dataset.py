"""The dataset generator behind ``lisa synth``: subjects of the open hand model, posed, scanned
and photographed by a multi-view rig, written in the layout of :mod:`lisa_hand.data.layout`
(documented file by file in ``docs/data_formats.md``).

Per subject ``k`` (:func:`make_subject`): a random hand (:func:`lisa_hand.handmodel.sample_hand`:
shape, appearance, detail seed), its side, and the MANO-like template fitted to it
(``template_betas``, ``template_rest_joints``: the skeleton LISA is trained with).

Per frame ``f`` of subject ``k`` (:func:`frame_setup`): a pose (a named pose with probability
``named_pose_fraction``, else a natural pose from :func:`lisa_hand.handmodel.sample_pose`), a
random global orientation (fingers up, a uniform turn about the vertical and a tilt of at most
``max_tilt_deg``), a translation that puts the centre of the hand's keypoints within
``translation_std`` of the rig's target (the origin), then

* ``mesh.ply``: the ground-truth mesh (marching cubes of the exact field, about 100k vertices
  at the default ``voxels_per_length``, vertex albedo and skinning weights);
* ``scan.npz``: a scan of that mesh (:func:`lisa_hand.data.scans.simulate_scan`, clean and full
  by default) with the exact skinning weights of the field at its points, the template's
  (nearest posed template vertex), and near-surface SDF samples (exact distances to the mesh,
  around clean surface samples, whatever the scan's noise);
* images, masks and depth of every camera (Embree ray casting of the same mesh,
  :func:`lisa_hand.data.images.render_views`, vertex albedo, the dataset's per-camera gain and
  bias), ``cameras.json`` and ``keypoints.json`` (projected, with occlusion from the depth map).

The rig (:func:`make_rig`, ``num_views`` cameras on a sphere around the origin, all looking at
it) and each camera's colour gain and bias are drawn once per dataset: the cameras and their
names are the same in every frame, as in a capture studio (the per-camera colour calibration of
LISA Section 4.2 is then learnable).

Determinism: every random choice comes from a ``numpy.random.SeedSequence`` keyed by
``(seed, stream, subject, frame)``, so subject ``k`` and its frame ``f`` are the same whatever the
numbers of subjects, poses and workers (each worker runs torch with one thread; the main process
too while it generates). Only ``scan.npz`` differs between two runs byte for byte (the ZIP
container stores the write time); its arrays are identical.

Split (:func:`split_subjects`, by subject, so test subjects never appear in training): with ``S``
subjects and fractions ``(train, val, test)``, ``num_test = max(1, round(test * S))`` when
``S >= 2`` (0 when ``S = 1``), ``num_val = round(val * S)`` reduced so that at least one subject
trains, ``num_train`` the rest; the subjects are shuffled by a seeded permutation and taken in
that order (test first, then val, then train); each list is sorted. Defaults 0.7/0.1/0.2: 20
subjects -> 14/2/4, 3 -> 2/0/1, 2 -> 1/0/1, 1 -> 1/0/0.

Timing, one frame at the defaults (about 120k mesh vertices, 20k scan points, 20k SDF samples)
and 8 views of 512x334, on one CPU core: about 3.5 s, of
which the mesh (the exact field on the coarse-to-fine grid, then albedo and weights at the
vertices) takes half, the SDF samples' closest points a quarter, the images, the scan and the
file writes the rest (``SynthSummary.stage_seconds`` has the per-stage sums of a run). Two
workers write 20 subjects x 10 poses (200 frames) in about 800 s of CPU.

Modules: :mod:`.synth_config` (settings and summary), :mod:`.synth_scene` (subjects, rig, frame
choices, split), :mod:`.synth_frame` (one frame's files), :mod:`.synth_preview` (the contact
sheet); this module runs them over the dataset.

All or nothing per subject: a run writes into the hidden ``OUT/.synth-staging`` and moves each
subject folder into ``OUT`` once all its frames are written; ``OUT/.synth-unfinished.json`` (the
settings) marks the dataset unfinished until ``dataset.json``, the last file, is written. A run
stopped half-way (a full disk, Ctrl-C) thus leaves complete subjects only, and the same command
run again continues it: the subjects already there are kept, the others written.

Worker processes are started with ``spawn``: a script that calls :func:`synthesize` with more
than one worker must guard its entry point with ``if __name__ == "__main__":`` (the ``lisa``
command does).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from concurrent.futures import Executor, Future, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from ...utils.io import ensure_writable_dir, is_no_space, no_space_error, write_json
from ...utils.pool import worker_pool
from ..layout import FORMAT_NAME, FORMAT_VERSION, prepare_dataset_folder, subject_id
from .config import SynthConfig, SynthSummary, parse_resolution
from .frame import write_frame
from .preview import write_preview
from .scene import (
    FrameSetup,
    SubjectRecord,
    dataset_rig,
    frame_setup,
    make_subject,
    split_subjects,
)

__all__ = [
    "GENERATOR_VERSION",
    "SynthConfig",
    "SynthSummary",
    "SubjectRecord",
    "FrameSetup",
    "parse_resolution",
    "split_subjects",
    "make_subject",
    "dataset_rig",
    "frame_setup",
    "synthesize",
    "write_preview",
]

GENERATOR_VERSION = 1
"""Version of the generator: bumped whenever the files written for a given seed change."""

UNFINISHED_FILE = ".synth-unfinished.json"
"""In the dataset folder while a run writes it: the settings; removed once ``dataset.json`` is
written."""
STAGING_DIR = ".synth-staging"
"""In the dataset folder while a run writes it: the subjects being written (each moved into the
dataset folder once complete)."""



# ------------------------------------------------------------------------------------------------
# Tasks (run in the worker processes, or in this one)

# The subject a worker is writing frames of (frames arrive subject by subject): rebuilt from its
# subject.json once, not once per frame.
_WORKER_SUBJECTS: dict[tuple, SubjectRecord] = {}


def _subject_task(config: SynthConfig, index: int) -> tuple[dict[str, Any], float]:
    start = time.perf_counter()
    record = make_subject(config, index)
    return record.to_json(), time.perf_counter() - start


def _worker_subject(config: SynthConfig, subject_json: dict[str, Any]) -> SubjectRecord:
    """The subject of ``subject_json`` (its hand rebuilt from the seed, its fitted template read
    back from the JSON), kept for the worker's next frames."""
    index = int(subject_json["id"][1:])
    key = (config, index)
    record = _WORKER_SUBJECTS.get(key)
    if record is None:
        record = make_subject(config, index, fit_template=False)
        record.template_betas = np.asarray(subject_json["template_betas"], np.float64)
        record.template_rest_joints = np.asarray(subject_json["template_rest_joints"],
                                                 np.float64)
        _WORKER_SUBJECTS.clear()  # frames arrive subject by subject: keep the current one
        _WORKER_SUBJECTS[key] = record
    return record


def _frame_task(root: str, config: SynthConfig, subject_json: dict[str, Any],
                frame: int) -> dict[str, float]:
    record = _worker_subject(config, subject_json)
    cameras, gain_bias = dataset_rig(config)
    return write_frame(Path(root), config, record, frame, cameras, gain_bias)


# ------------------------------------------------------------------------------------------------
# The dataset


def _run_tasks(out: Path, config: SynthConfig, executor: Executor, bar,
               todo: list[int]) -> dict[str, float]:
    """Subjects ``todo`` first (their ``subject.json`` written here, in order, into the staging
    folder), then every frame of them; each subject moved into ``out`` once its frames are
    written. -> seconds per stage summed over the tasks."""
    staging = out / STAGING_DIR
    stage_seconds: dict[str, float] = {"subject": 0.0}
    futures = [executor.submit(_subject_task, config, k) for k in todo]
    subjects: dict[str, dict[str, Any]] = {}
    for future in futures:
        subject_json, seconds = future.result()
        subjects[subject_json["id"]] = subject_json
        stage_seconds["subject"] += seconds
        write_json(staging / subject_json["id"] / "subject.json", subject_json)
        bar.update(1)
    left = {name: config.num_poses for name in subjects}
    frame_futures = {executor.submit(_frame_task, str(staging), config, subject, f): name
                     for name, subject in subjects.items() for f in range(config.num_poses)}
    counted: set[Future] = set()

    def frame_done(future: Future) -> None:
        counted.add(future)
        name = frame_futures[future]
        left[name] -= 1
        if left[name] == 0:  # the subject is complete: into the dataset as a whole
            os.rename(staging / name, out / name)

    try:
        for future in as_completed(frame_futures):
            for stage, seconds in future.result().items():
                stage_seconds[stage] = stage_seconds.get(stage, 0.0) + seconds
            frame_done(future)
            bar.update(1)
    except BaseException:
        # The frames written before the failure still count: their complete subjects are kept.
        for future in frame_futures:
            future.cancel()
        for future in frame_futures:
            if (future not in counted and future.done() and not future.cancelled()
                    and future.exception() is None):
                frame_done(future)
        raise
    return stage_seconds


def _unfinished_record(config: SynthConfig) -> dict[str, Any]:
    """What :data:`UNFINISHED_FILE` holds: the generator version and the settings, as JSON
    reads them back."""
    record = {"generator_version": GENERATOR_VERSION, "config": config.to_dict()}
    return json.loads(json.dumps(record))


def _unfinished_subjects(out: Path, config: SynthConfig) -> list[str] | None:
    """The complete subjects of an unfinished dataset of ``config`` in ``out`` (a run of the
    same settings stopped half-way), or None when ``out`` is not one (no marker, other settings,
    a ``dataset.json``, or entries the generator does not write)."""
    marker = out / UNFINISHED_FILE
    if not marker.is_file() or (out / "dataset.json").exists():
        return None
    try:
        if json.loads(marker.read_text()) != _unfinished_record(config):
            return None
    except (OSError, ValueError):
        return None
    names = {entry.name for entry in out.iterdir()}
    subjects = {subject_id(k) for k in range(config.num_subjects)}
    if not names <= subjects | {UNFINISHED_FILE, STAGING_DIR}:
        return None
    return sorted(names & subjects)


def _dataset_json(config: SynthConfig, camera_names: list[str],
                  split: dict[str, list[str]]) -> dict[str, Any]:
    """The contents of ``dataset.json`` (see ``docs/data_formats.md``)."""
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "generator": "lisa_hand.data.synth.dataset",
        "generator_version": GENERATOR_VERSION,
        "lisa_hand_version": _package_version(),
        "config": config.to_dict(),
        "num_subjects": config.num_subjects,
        "num_poses": config.num_poses,
        "num_frames": config.num_frames,
        "num_views": config.num_views,
        "width": config.width,
        "height": config.height,
        "camera_names": camera_names,
        "split_counts": {name: len(ids) for name, ids in split.items()},
    }


def synthesize(out: str | os.PathLike, config: SynthConfig | None = None, progress: bool = True,
               overwrite: bool = False) -> SynthSummary:
    """Write a dataset (layout of :mod:`lisa_hand.data.layout`) into the folder ``out``.

    out: the dataset folder; created if missing, must be empty unless ``overwrite`` (which first
        removes a previous dataset's subject folders s000..., ``dataset.json`` and
        ``split.json``, nothing else), or an unfinished dataset of the same settings, which is
        continued (see the module docstring).
    config: what to write (default :class:`SynthConfig()`).
    progress: show a tqdm bar over the frames.
    Raises FileExistsError for a non-empty ``out``, OSError for an unwritable one (a full disk:
    ``NoSpaceError`` naming ``out``, the subjects complete, and that a rerun continues),
    ValueError for bad settings. ``dataset.json`` is written last: a folder without it is
    unfinished.
    -> :class:`SynthSummary` (counts, split, wall-clock seconds, seconds per stage).
    """
    config = SynthConfig() if config is None else config
    if not isinstance(config, SynthConfig):
        raise TypeError(f"config must be a SynthConfig, got {type(config).__name__}")
    out = Path(out)
    done = None if overwrite or not out.is_dir() else _unfinished_subjects(out, config)
    if done is None:
        prepare_dataset_folder(out, overwrite, "--overwrite (overwrite=True)")
        done = []
    else:
        ensure_writable_dir(out)
        if progress:
            print(f"synth: {out}: continuing an unfinished dataset of these settings "
                  f"({len(done)} of {config.num_subjects} subjects already written)",
                  file=sys.stderr, flush=True)
    shutil.rmtree(out / STAGING_DIR, ignore_errors=True)  # a stopped run's partial subjects
    write_json(out / UNFINISHED_FILE, _unfinished_record(config))
    start = time.perf_counter()
    from tqdm.auto import tqdm

    split = split_subjects(config.num_subjects, config.split_fractions, config.seed)
    cameras, _ = dataset_rig(config)
    todo = [k for k in range(config.num_subjects) if subject_id(k) not in done]
    num_workers = config.workers()
    executor = worker_pool(num_workers)
    bar = tqdm(total=len(todo) * (1 + config.num_poses), desc="synth", unit="task",
               disable=not progress, dynamic_ncols=True)
    try:
        stage_seconds = _run_tasks(out, config, executor, bar, todo)
    except BaseException as exc:
        executor.shutdown(wait=True, cancel_futures=True)
        if isinstance(exc, Exception) and is_no_space(exc):
            complete = sum((out / subject_id(k)).is_dir() for k in range(config.num_subjects))
            raise no_space_error(out, then=(
                f"{complete} of {config.num_subjects} subjects are complete; free some space "
                "and run the same command again to continue")) from None
        raise
    finally:
        bar.close()
    executor.shutdown(wait=True)

    shutil.rmtree(out / STAGING_DIR, ignore_errors=True)
    write_json(out / "split.json", split)
    write_json(out / "dataset.json", _dataset_json(config, [c.name for c in cameras], split))
    (out / UNFINISHED_FILE).unlink(missing_ok=True)
    return SynthSummary(root=out, num_subjects=config.num_subjects, num_frames=config.num_frames,
                        num_views=config.num_views,
                        num_images=config.num_frames * config.num_views, split=split,
                        seconds=time.perf_counter() - start, num_workers=num_workers,
                        stage_seconds=stage_seconds)


def _package_version() -> str:
    from ... import __version__

    return __version__
