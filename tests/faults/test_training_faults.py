"""Faults around training runs and written folders, each made by the test itself: a resume with a
changed learning rate, a full disk while writing a checkpoint, a log line or a synthetic dataset,
two writers into one fit folder, and a fit folder whose parent cannot be written."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import shutil
import signal
import socket

import numpy as np
import pytest
import torch

from lisa_hand.cli.main import error_line
from lisa_hand.fitting.outputs import (
    check_output_folder,
    lock_output_folder,
    prepare_fit,
    releases_output_locks,
    unlock_output_folder,
    write_fit_outputs,
)
from lisa_hand.fitting.outputs import folder as outputs
from lisa_hand.geometry.meshing import Mesh
from lisa_hand.model.checkpoint import load_checkpoint
from lisa_hand.skeleton.params import HandParams
from lisa_hand.training.config import TrainerConfig, lr_factor
from lisa_hand.training.engine import CONFIG_FILE, Trainer, train
from lisa_hand.training.progress import LOG_FILE, RunLog
from lisa_hand.utils.io import NoSpaceError, write_json
from lisa_hand.utils.threads import cpu_threads
from tests.training.toy import make_model, make_step_fn

DEAD_PID = 2**22 + 12345  # above the kernel's largest pid_max (2^22): no process has this id


@pytest.fixture(autouse=True)
def _one_thread():
    with cpu_threads(1):
        yield


def _config(**kwargs) -> TrainerConfig:
    base = dict(steps=12, lr=1e-2, lr_schedule="cosine", checkpoint_every=4, device="cpu",
                progress=False, seed=5)
    base.update(kwargs)
    return TrainerConfig(**base)


def _log(run_dir) -> list[dict]:
    return [json.loads(line) for line in (run_dir / LOG_FILE).read_text().splitlines()]


def _one_line(exc: BaseException, starts: str) -> str:
    line = error_line(exc)
    assert line.startswith(starts) and "\n" not in line, line
    assert "/." not in line.replace("/.fit.lock", "") and "Errno" not in line, line  # no hidden
    return line  # temporary (the lock only, to delete when no fit runs), no bare errno


# ------------------------------------------------------------------------------------------------
# resume with a changed optimizer setting


def _stop_at(step):
    def hook(info):
        if info.step == step:
            os.kill(os.getpid(), signal.SIGINT)  # a Ctrl-C: the trainer finishes the step
    return hook


def test_a_resume_applies_a_changed_learning_rate(tmp_path, capsys):
    first = tmp_path / "first"
    stopped = train(make_model(0), make_step_fn(), _config(), first, hooks=[_stop_at(5)])
    assert stopped.status == "interrupted" and stopped.steps_done == 6
    shutil.copytree(first, tmp_path / "changed")
    capsys.readouterr()

    same = make_model(0)
    train(same, make_step_fn(), _config(), first)
    assert "optimizer settings" not in capsys.readouterr().err

    changed = make_model(0)
    new = _config(lr=3e-2)
    train(changed, make_step_fn(), new, tmp_path / "changed")
    err = capsys.readouterr().err
    assert "with this run's optimizer settings, not the checkpoint's: lr 0.01 -> 0.03" in err
    # The run with the new rate is another run, on the new schedule from the resumed step on.
    assert not torch.equal(same.layers[0].weight, changed.layers[0].weight)
    rates = {entry["step"]: entry["lr"] for entry in _log(tmp_path / "changed")}
    for step in range(6, 12):
        assert rates[step] == pytest.approx(3e-2 * lr_factor(step, new), rel=1e-12)
    for step in range(6):
        assert rates[step] == pytest.approx(1e-2 * lr_factor(step, _config()), rel=1e-12)
    ckpt = load_checkpoint(tmp_path / "changed" / "last.pt")
    assert ckpt.scheduler["base_lrs"] == [3e-2]
    assert ckpt.optimizer["param_groups"][0]["initial_lr"] == 3e-2
    assert json.loads((tmp_path / "changed" / CONFIG_FILE).read_text())["lr"] == 3e-2


def test_resume_notes_name_the_command_that_runs(tmp_path, capsys):
    run = tmp_path / "run"
    train(make_model(0), make_step_fn(), _config(steps=4), run)
    capsys.readouterr()
    Trainer(make_model(0), make_step_fn(), _config(steps=8), run, name="lisa train-prior").run()
    err = capsys.readouterr().err
    assert "lisa train-prior: resuming" in err and "lisa train:" not in err


def test_a_resume_applies_other_optimizer_settings_and_a_changed_schedule(tmp_path, capsys):
    train(make_model(0), make_step_fn(), _config(steps=8), tmp_path, hooks=[_stop_at(3)])
    capsys.readouterr()
    config = _config(steps=8, weight_decay=0.1, betas=(0.8, 0.99), lr_schedule="constant")
    trainer = Trainer(make_model(0), make_step_fn(), config, tmp_path)
    group = trainer.optimizer.param_groups[0]
    assert group["weight_decay"] == 0.1 and tuple(group["betas"]) == (0.8, 0.99)
    assert group["lr"] == 1e-2  # the constant schedule from the first resumed step
    err = capsys.readouterr().err
    assert "weight_decay 0.0 -> 0.1" in err and "betas" in err and "lr 0.01" not in err


# ------------------------------------------------------------------------------------------------
# a full disk


def _full_disk_save(fail_on: set[int], wrapped: bool):
    """A ``torch.save`` that writes part of the file, then meets a full disk on the calls
    ``fail_on`` (1-based), as torch does (wrapped: its RuntimeError over the OSError)."""
    real = torch.save
    calls = []

    def save(obj, handle, *args, **kwargs):
        calls.append(1)
        if len(calls) not in fail_on:
            return real(obj, handle, *args, **kwargs)
        handle.write(b"PK" + b"\0" * 100)
        full = OSError(errno.ENOSPC, "No space left on device")
        if not wrapped:
            raise full
        try:
            raise full
        except OSError:
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos "
                               "704 vs 598") from None  # torch drops the cause, keeps context

    return save


@pytest.mark.parametrize("wrapped", [True, False])
def test_a_full_disk_while_checkpointing_is_one_line_and_keeps_the_last_checkpoint(
        tmp_path, monkeypatch, wrapped):
    monkeypatch.setattr(torch, "save", _full_disk_save({2}, wrapped))
    with pytest.raises(NoSpaceError) as caught:
        train(make_model(0), make_step_fn(), _config(steps=8), tmp_path)
    line = _one_line(caught.value, f"{tmp_path / 'last.pt'}: no space left on device (")
    assert "MB free there, about" in line and "MB needed)" in line
    assert line.endswith("the previous checkpoint is left intact")
    assert caught.value.errno == errno.ENOSPC
    assert load_checkpoint(tmp_path / "last.pt").step == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == [CONFIG_FILE, "last.pt", LOG_FILE]
    monkeypatch.undo()
    resumed = train(make_model(0), make_step_fn(), _config(steps=8), tmp_path)
    assert resumed.start_step == 4 and resumed.steps_done == 8


def test_a_full_disk_while_logging_names_the_log(tmp_path):
    class FullFile:
        name = str(tmp_path / LOG_FILE)

        def write(self, text):
            raise OSError(errno.ENOSPC, "No space left on device")

        def flush(self):
            pass

        def close(self):
            raise OSError(errno.ENOSPC, "No space left on device")

    log = RunLog(tmp_path, 0, True)
    log._file.close()
    log._file = FullFile()
    with pytest.raises(NoSpaceError) as caught:
        log.write({"step": 0})
    _one_line(caught.value, f"{tmp_path / LOG_FILE}: no space left on device (")
    with pytest.raises(NoSpaceError, match="log.jsonl: no space left on device"):
        log.close()


def test_a_full_disk_in_an_atomic_write_names_the_file_not_the_temporary(tmp_path, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(json, "dumps", full)
    with pytest.raises(NoSpaceError) as caught:
        write_json(tmp_path / "a.json", {"x": 1})
    _one_line(caught.value, f"{tmp_path / 'a.json'}: no space left on device (")
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_writing_a_fit_names_the_out_folder(tmp_path, monkeypatch):
    out = tmp_path / "fit"
    import lisa_hand.data.meshio as meshio

    def full(path, mesh):
        open(path, "wb").write(b"ply\n")
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(meshio, "save_mesh", full)
    with pytest.raises(NoSpaceError) as caught:
        write_fit_outputs(out, _hand(), MESH)
    _one_line(caught.value, f"{out}: no space left on device (")
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no staging, no lock, no folder


SYNTH = dict(num_subjects=2, num_poses=1, num_views=1, resolution=(32, 24), seed=0,
             num_sdf_samples=100, voxels_per_length=30, num_workers=1)


def test_a_full_disk_in_synth_keeps_whole_subjects_and_the_rerun_continues(tmp_path,
                                                                           monkeypatch):
    from lisa_hand.data.scans import ScanConfig
    from lisa_hand.data.synth import dataset
    from lisa_hand.data.synth.dataset import SynthConfig, synthesize

    config = SynthConfig(scan=ScanConfig(num_points=200), **SYNTH)
    out = tmp_path / "data"
    real = dataset.write_frame

    def full_on_s001(root, config, subject, frame, *args):
        if subject.id == "s001":
            (root / "s001" / "f000").mkdir(parents=True)
            (root / "s001" / "f000" / "mesh.ply").write_bytes(b"half")
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(root, config, subject, frame, *args)

    monkeypatch.setattr(dataset, "write_frame", full_on_s001)
    with pytest.raises(NoSpaceError) as caught:
        synthesize(out, config, progress=False)
    line = _one_line(caught.value, f"{out}: no space left on device (")
    assert line.endswith("1 of 2 subjects are complete; free some space and run the same "
                         "command again to continue")
    assert (out / "s000" / "f000" / "mesh.ply").is_file() and not (out / "s001").exists()
    assert not (out / "dataset.json").exists()
    kept = (out / "s000" / "subject.json").stat().st_mtime_ns

    monkeypatch.undo()
    summary = synthesize(out, config, progress=False)  # the same command: it continues
    assert summary.num_frames == 2
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "s000", "s001",
                                                     "split.json"]
    assert (out / "s000" / "subject.json").stat().st_mtime_ns == kept  # not written again
    assert (out / "s001" / "f000" / "mesh.ply").read_bytes() != b"half"
    # A finished dataset is not continued: it is refused as before.
    with pytest.raises(FileExistsError, match="not empty"):
        synthesize(out, config, progress=False)
    # An unfinished dataset of other settings is not continued either.
    (out / "dataset.json").unlink()
    (out / dataset.UNFINISHED_FILE).write_text(json.dumps({"config": {}}))
    with pytest.raises(FileExistsError, match="not empty"):
        synthesize(out, dataclasses.replace(config, seed=1), progress=False)


# ------------------------------------------------------------------------------------------------
# fit folders: one writer at a time, a parent that cannot be written


def _hand() -> HandParams:
    rest = torch.zeros(16, 3)
    rest[:, 0] = torch.linspace(0.0, 0.15, 16)  # bones of 10 mm: a plausible skeleton
    return HandParams(pose=torch.zeros(48), translation=torch.zeros(3), rest_joints=rest,
                      shape_code=torch.zeros(4))


MESH = Mesh(vertices=np.eye(3), faces=np.array([[0, 1, 2]]))


def test_a_second_writer_into_a_claimed_folder_is_refused(tmp_path):
    out = tmp_path / "fit"
    write_fit_outputs(out, _hand(), MESH)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    lock = tmp_path / ".fit.lock"
    assert not lock.exists()  # freed after the write
    # Another fit (a live process that is not this one) holds the folder.
    lock.write_text(f"{os.getppid()} {socket.gethostname()}\n")
    with pytest.raises(FileExistsError) as caught:
        write_fit_outputs(out, _hand(), MESH, {"psnr_db": 1.0})
    line = _one_line(caught.value, f"{out}: another fit (process {os.getppid()}) is writing "
                                   "this folder")
    assert "choose another --out" in line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert lock.read_text().split()[0] == str(os.getppid())  # left to its owner
    with pytest.raises(FileExistsError, match="another fit"):
        lock_output_folder(out)
    # Its process ended without freeing it (kill -9): the next writer takes it over.
    lock.write_text(f"{DEAD_PID} {socket.gethostname()}\n")
    write_fit_outputs(out, _hand(), MESH, {"psnr_db": 1.0})
    assert "metrics.json" in {p.name for p in out.iterdir()} and not lock.exists()


def test_a_fit_holds_its_folder_from_the_check_to_the_end(tmp_path):
    out = tmp_path / "fit"

    @releases_output_locks
    def fit():
        prepare_fit(out, None, "auto", tmp_path / "model.pt", "cpu", print)

    # prepare_fit claims the folder after checking it, before loading the model; a failure
    # anywhere in the fit frees it.
    with pytest.raises(OSError, match="model.pt"):
        fit()
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    assert lock_output_folder(out) == tmp_path / ".fit.lock"  # held: a second claim is a no-op
    assert lock_output_folder(out) == tmp_path / ".fit.lock"
    write_fit_outputs(out, _hand(), MESH)  # this process's own fit writes; still held after
    assert (tmp_path / ".fit.lock").read_text().split()[0] == str(os.getpid())
    unlock_output_folder(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"]


def test_an_out_whose_parent_cannot_be_written_is_refused_before_the_fit(tmp_path):
    if os.geteuid() == 0:  # chmod does not stop root: a parent that is a file instead
        parent = tmp_path / "afile"
        parent.write_text("")
        out = parent / "fit"
        with pytest.raises(NotADirectoryError) as caught:
            prepare_fit(out, None, "auto", tmp_path / "no_model.pt", "cpu", print)
        _one_line(caught.value, f"{out}: ")
        assert "afile is a file" in error_line(caught.value)
        return
    parent = tmp_path / "locked"
    out = parent / "fit"
    out.mkdir(parents=True)  # --out itself is writable, the folder holding it is not
    parent.chmod(0o555)
    try:
        with pytest.raises(PermissionError) as caught:
            prepare_fit(out, None, "auto", tmp_path / "no_model.pt", "cpu", print)
        line = _one_line(caught.value, f"{out}: cannot write the fit: the folder holding it, "
                                       f"{parent}, is not writable")
        assert "no_model" not in line
        with pytest.raises(PermissionError, match="cannot write the fit"):
            check_output_folder(out)
        with pytest.raises(PermissionError, match="cannot write the fit"):
            write_fit_outputs(out, _hand(), MESH)
    finally:
        parent.chmod(0o755)
    assert list(out.iterdir()) == [] and sorted(p.name for p in parent.iterdir()) == ["fit"]
    assert not outputs._HELD_LOCKS
