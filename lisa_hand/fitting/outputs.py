"""What a fit writes: ``params.json``, ``mesh.ply`` and ``metrics.json``, all or nothing.

Shared by the fitting commands (``lisa fit-points`` and ``lisa fit-images``):

* :func:`check_output_folder` fails before a long fit when ``--out`` cannot be written, or
  holds files that a fit does not write;
* :func:`read_ground_truth` reads a ``--gt`` mesh or point set (errors name the file) and
  :func:`ground_truth_metrics` gives the paper's four distances (V2V and V2S, both ways, mm);
* :func:`write_fit_outputs` writes the files into a hidden folder beside ``out_dir`` and swaps it
  in as a whole once all exist.

A reused ``--out`` is replaced as a whole: after a fit it holds exactly that fit's files (a
``metrics.json`` of an earlier fit with ``--gt`` does not survive a fit without it). Like
``lisa synth``, a fit never deletes what it did not write: a folder holding anything but
:data:`FIT_FILES` is refused before the work. A ``kill -9`` while the files are written leaves a
hidden ``.OUT.staging-PID-*`` (or ``.OUT.old-PID-*``) folder beside ``OUT``; the next fit into
``OUT`` removes it (:func:`remove_stale_staging`).
"""

from __future__ import annotations

import math
import os
import secrets
import shutil
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..data.units import UNIT_CHOICES, decide_length_unit
from ..geometry.meshing import Mesh
from ..skeleton.params import HandParams
from ..utils.io import check_output_dir

__all__ = [
    "FIT_FILES",
    "GroundTruth",
    "check_output_folder",
    "remove_stale_staging",
    "read_ground_truth",
    "ground_truth_metrics",
    "json_safe",
    "write_fit_outputs",
]

FIT_FILES = ("params.json", "mesh.ply", "metrics.json")
"""The files a fit writes into its output folder (``metrics.json`` only with metrics)."""


@dataclass
class GroundTruth:
    """A ground-truth surface for the metrics.

    vertices: [V, 3] float64 metres. faces: [F, 3] int64, or None for a point set.
    unit: the unit the file was read in ("m", "cm" or "mm"). note: a sentence naming the file
    when the unit was guessed as other than metres, else None. path: the file.
    """

    vertices: np.ndarray
    faces: np.ndarray | None
    unit: str
    note: str | None
    path: Path


def check_output_folder(out: str | os.PathLike) -> Path:
    """Fail before a (long) fit when ``out`` cannot become the fit's folder. Creates nothing.

    Raises NotADirectoryError when ``out`` (or an ancestor) is a file, PermissionError when the
    folder or its nearest existing ancestor is not writable, and FileExistsError when ``out``
    holds anything but :data:`FIT_FILES` (a fit replaces the folder as a whole and never
    deletes what it did not write).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: --out must be a folder, and this is a file")
    check_output_dir(out)
    if out.is_dir():
        foreign = sorted(p.name for p in out.iterdir() if p.name not in FIT_FILES
                         or not p.is_file())
        if foreign:
            shown = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "")
            raise FileExistsError(
                f"{out}: output folder holds files a fit does not write ({shown}); a fit "
                f"replaces the folder as a whole, so choose a new or empty folder (or one "
                f"holding only a previous fit's {', '.join(FIT_FILES)})")
    return out


def read_ground_truth(path: str | os.PathLike, units: str = "auto") -> GroundTruth:
    """Read a ground-truth mesh or point set (:func:`lisa_hand.metrics.load_mesh`) in metres.

    units: "m", "cm", "mm" or "auto" (:func:`lisa_hand.data.units.decide_length_unit`: the
    unit in which the file is a hand's size; a given unit that makes no hand is an error naming
    the ``--units`` that fits).
    """
    from ..metrics import load_mesh

    if units not in UNIT_CHOICES:
        raise ValueError(f"units must be one of {', '.join(UNIT_CHOICES)}, got {units!r}")
    path = Path(path)
    data = load_mesh(path)
    length = decide_length_unit(data.vertices, units, name=str(path), what="the ground truth")
    note = None if length.note is None else f"{path}: {length.note}"
    vertices = np.asarray(data.vertices, dtype=np.float64)
    if length.unit != "m":
        vertices = vertices * length.metres_per_unit
    return GroundTruth(vertices=vertices, faces=data.faces, unit=length.unit, note=note,
                       path=path)


def prepare_fit(
    out_dir: str | os.PathLike, gt_path: str | os.PathLike | None, units: str,
    model_path: str | os.PathLike | None, device: str, log,
) -> tuple[GroundTruth | None, Any]:
    """What both fit commands check before fitting, in this order so that bad input fails
    before the slow part: the ground truth (``gt_path``, its unit note logged), the output
    folder, then the model (:func:`lisa_hand.model.trained.load_trained` on ``device``).
    -> (the ground truth or None, the :class:`~lisa_hand.model.trained.TrainedModel`)."""
    from ..model.trained import load_trained
    from ..utils.device import resolve_device

    truth = None
    if gt_path is not None:
        truth = read_ground_truth(gt_path, units)
        if truth.note is not None:
            log(truth.note)
    check_output_folder(out_dir)
    return truth, load_trained(model_path, resolve_device(device))


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, inf) replaced by None, recursively (JSON has
    no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    return value


def ground_truth_metrics(mesh: Mesh, truth: GroundTruth) -> dict[str, float | None]:
    """V2V and V2S distances (mm) between a fitted mesh and the ground truth, both ways
    (:func:`lisa_hand.metrics.mesh_distances`; None where undefined: V2S towards points)."""
    from ..metrics import mesh_distances

    distances = mesh_distances(mesh.vertices, mesh.faces, truth.vertices, truth.faces)
    return json_safe(distances.to_dict())


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process, or no permission to ask: assume it runs
        return True
    return True


def remove_stale_staging(out_dir: str | os.PathLike) -> list[Path]:
    """Remove the hidden folders a killed fit left beside ``out_dir``; return them.

    :func:`write_fit_outputs` stages into ``.OUT.staging-PID-*`` and moves the previous fit to
    ``.OUT.old-PID-*`` for the swap; only a ``kill -9`` leaves them. Folders whose process
    still runs (a fit writing into ``out_dir`` right now) are kept.
    """
    target = Path(os.path.abspath(out_dir))
    removed = []
    if not target.parent.is_dir():
        return removed
    prefixes = [f".{target.name}.{kind}-" for kind in ("staging", "old")]
    for stale in sorted(target.parent.iterdir()):
        prefix = next((p for p in prefixes if stale.name.startswith(p)), None)
        if prefix is None or not stale.is_dir():
            continue
        pid_text = stale.name[len(prefix):].split("-", 1)[0]
        if pid_text.isdigit() and not _pid_alive(int(pid_text)):
            shutil.rmtree(stale, ignore_errors=True)
            removed.append(stale)
    return removed


def _can_swap(target: Path) -> bool:
    """Whether ``target`` may be renamed away: not the working folder (or above it), not a
    mount point."""
    cwd = Path.cwd()
    return not (target == cwd or target in cwd.parents or os.path.ismount(target))


def _swap_in(staging: Path, target: Path) -> None:
    """Make ``staging`` the folder ``target``: two renames, the previous folder removed after.

    At every moment ``target`` is the previous folder or the new one, except between the two
    renames (microseconds; a kill there leaves both hidden folders, which the next fit
    removes). Where ``target`` cannot be renamed away, the files are moved in one by one and
    the previous fit's other files removed.
    """
    if not target.exists():
        os.rename(staging, target)
        return
    if _can_swap(target):
        old = target.parent / f".{target.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
        try:
            os.rename(target, old)
        except OSError:
            pass  # busy or not ours to rename: fall back to moving the files
        else:
            os.rename(staging, target)
            shutil.rmtree(old, ignore_errors=True)
            return
    names = [file.name for file in staging.iterdir()]
    for name in names:
        os.replace(staging / name, target / name)
    for name in FIT_FILES:
        if name not in names and (target / name).is_file():
            (target / name).unlink()


def write_fit_outputs(
    out_dir: str | os.PathLike,
    params: HandParams,
    mesh: Mesh,
    metrics: dict[str, Any] | None = None,
) -> list[Path]:
    """Write ``params.json``, ``mesh.ply`` and (when ``metrics`` is given) ``metrics.json`` as
    the folder ``out_dir`` (created), all or nothing.

    The files go into a hidden staging folder beside ``out_dir`` first, which then replaces
    ``out_dir`` as a whole (two renames): the folder holds this fit's files and nothing
    else (a previous fit's ``metrics.json`` does not survive). ``out_dir`` must be new, empty or
    hold only :data:`FIT_FILES` (:func:`check_output_folder`). Stale staging folders of killed
    fits into ``out_dir`` are removed first (:func:`remove_stale_staging`).
    -> the written paths, in that order.
    """
    from ..data.meshio import save_mesh
    from ..skeleton.params import write_params
    from ..utils.io import write_json

    out_dir = check_output_folder(out_dir)
    target = Path(os.path.abspath(out_dir))
    if target.is_symlink():
        target = target.resolve()
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(target)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.staging-{os.getpid()}-",
                                    dir=target.parent))
    try:
        # mkdtemp makes the folder 0700: give it the previous folder's mode, or the usual one.
        umask = os.umask(0)
        os.umask(umask)
        mode = stat.S_IMODE(target.stat().st_mode) if target.is_dir() else 0o777 & ~umask
        os.chmod(staging, mode)
        files = [write_params(staging / "params.json", params),
                 save_mesh(staging / "mesh.ply", mesh)]
        if metrics is not None:
            files.append(write_json(staging / "metrics.json", json_safe(metrics)))
        _swap_in(staging, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return [out_dir / file.name for file in files]
