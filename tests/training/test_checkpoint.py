"""Checkpoints: round trip with the random state, corrupt/foreign files, the finite guard."""

from __future__ import annotations

import random
from collections import OrderedDict

import numpy as np
import pytest
import torch

from lisa_hand.model.checkpoint import CHECKPOINT_VERSION, Checkpoint, load_checkpoint
from lisa_hand.training.checkpoint import (
    NonFiniteError,
    capture_rng_state,
    check_finite_state,
    remove_stale_temporaries,
    restore_rng_state,
    save_checkpoint,
)

from .toy import make_model


def _trained_state(seed: int = 0):
    model = make_model(seed)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: 0.9 ** step)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(3):
        optimizer.zero_grad()
        model(torch.rand(8, 3, generator=gen)).pow(2).mean().backward()
        optimizer.step()
        scheduler.step()
    return model, optimizer, scheduler, gen


def _draws(gen: torch.Generator):
    return (torch.rand(4).tolist(), torch.rand(4, generator=gen).tolist(),
            np.random.rand(3).tolist(), np.random.randn(), random.random())


def test_round_trip_restores_every_state(tmp_path):
    model, optimizer, scheduler, gen = _trained_state()
    torch.manual_seed(1)
    np.random.seed(2)
    np.random.randn()  # leaves a cached gaussian in numpy's state
    random.seed(3)
    ckpt = Checkpoint(step=3, model=model.state_dict(), optimizer=optimizer.state_dict(),
                      scheduler=scheduler.state_dict(), rng=[capture_rng_state({"data": gen})],
                      config={"a": [1, 2], "b": {"c": "d"}}, trainer={"steps": 3},
                      extra={"scale": torch.tensor([2.0]), "note": "x"})
    expected_draws = _draws(gen)
    path = save_checkpoint(tmp_path / "run" / "last.pt", ckpt)
    assert not list(path.parent.glob(".last.pt*"))

    loaded = load_checkpoint(path)
    assert loaded.path == path and loaded.step == 3
    assert loaded.config == {"a": [1, 2], "b": {"c": "d"}} and loaded.trainer == {"steps": 3}
    assert loaded.extra["note"] == "x" and torch.equal(loaded.extra["scale"], torch.tensor([2.0]))

    fresh, fresh_opt, fresh_sched, fresh_gen = _trained_state(seed=9)  # different everything
    fresh.load_state_dict(loaded.model)
    fresh_opt.load_state_dict(loaded.optimizer)
    fresh_sched.load_state_dict(loaded.scheduler)
    for key, value in model.state_dict().items():
        assert torch.equal(fresh.state_dict()[key], value)
    for state, fresh_state in zip(optimizer.state.values(), fresh_opt.state.values(),
                                  strict=True):
        for key in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(state[key], fresh_state[key])
    assert fresh_sched.last_epoch == 3 and fresh_opt.param_groups[0]["lr"] == pytest.approx(
        1e-2 * 0.9 ** 3)

    torch.manual_seed(99)
    np.random.seed(99)
    random.seed(99)
    restore_rng_state(loaded.rng[0], {"data": fresh_gen})
    assert _draws(fresh_gen) == expected_draws


def test_restore_refuses_a_missing_generator():
    state = capture_rng_state({"data": torch.Generator()})
    with pytest.raises(ValueError, match="no state for generator 'noise'"):
        restore_rng_state(state, {"noise": torch.Generator()})


def _good_file(tmp_path):
    model = make_model()
    return save_checkpoint(tmp_path / "last.pt", Checkpoint(step=1, model=model.state_dict()))


def test_missing_corrupt_truncated_and_foreign_files_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothing\.pt: no such checkpoint file"):
        load_checkpoint(tmp_path / "nothing.pt")

    junk = tmp_path / "junk.pt"
    junk.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(ValueError, match=rf"{junk}: not a readable checkpoint"):
        load_checkpoint(junk)

    good = _good_file(tmp_path)
    data = good.read_bytes()
    cut = tmp_path / "cut.pt"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=rf"{cut}: not a readable checkpoint"):
        load_checkpoint(cut)

    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": make_model().state_dict()}, foreign)
    with pytest.raises(ValueError, match=rf"{foreign}: not a lisa_hand training checkpoint"):
        load_checkpoint(foreign)

    pickled = tmp_path / "pickled.pt"
    torch.save({"format": "lisa_hand.checkpoint", "obj": OrderedDictSub()}, pickled)
    with pytest.raises(ValueError, match=rf"{pickled}: not a readable checkpoint"):
        load_checkpoint(pickled)  # weights_only: arbitrary classes are refused

    newer = tmp_path / "newer.pt"
    torch.save({"format": "lisa_hand.checkpoint", "version": CHECKPOINT_VERSION + 1,
                "step": 0, "model": {}}, newer)
    with pytest.raises(ValueError, match=rf"{newer}: checkpoint version"):
        load_checkpoint(newer)

    bad_step = tmp_path / "bad_step.pt"
    torch.save({"format": "lisa_hand.checkpoint", "version": 1, "step": "3", "model": {}},
               bad_step)
    with pytest.raises(ValueError, match=rf"{bad_step}: checkpoint is missing or has a bad "
                                         "'step'"):
        load_checkpoint(bad_step)


class OrderedDictSub(OrderedDict):
    """A class the safe loader does not know."""


def test_non_finite_model_is_never_written(tmp_path):
    path = _good_file(tmp_path)
    before = path.read_bytes()
    model = make_model()
    with torch.no_grad():
        model.layers[2].weight[0, 3] = float("nan")
        model.layers[2].weight[0, 5] = float("inf")
    with pytest.raises(NonFiniteError, match=r"parameter 'layers.2.weight' has 2 non-finite"):
        save_checkpoint(path, Checkpoint(step=2, model=model.state_dict()))
    assert path.read_bytes() == before
    assert load_checkpoint(path).step == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.pt"]


def test_check_finite_state_ignores_integer_tensors():
    check_finite_state({"count": torch.tensor([3]), "w": torch.zeros(2)}, "x")
    with pytest.raises(NonFiniteError, match="x: parameter 'w'"):
        check_finite_state({"count": torch.tensor([3]), "w": torch.tensor([0.0, -np.inf])}, "x")


def test_a_failed_write_leaves_the_previous_checkpoint(tmp_path, monkeypatch):
    path = _good_file(tmp_path)
    before = path.read_bytes()

    def broken_save(obj, handle):
        handle.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        save_checkpoint(path, Checkpoint(step=5, model=make_model().state_dict()))
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.pt"]


def test_remove_stale_temporaries(tmp_path):
    path = _good_file(tmp_path)
    stale = tmp_path / ".last.pt.abc123.pt"
    stale.write_bytes(b"half")
    other = tmp_path / ".other.pt.x.pt"
    other.write_bytes(b"keep")
    assert remove_stale_temporaries(path) == [stale]
    assert path.exists() and other.exists() and not stale.exists()
