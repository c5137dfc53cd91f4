"""cpu_threads and the worker pool: the thread count is set for a block and given back."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from lisa_hand.utils.pool import run_tasks, worker_pool
from lisa_hand.utils.threads import cpu_threads


def _threads_in_worker(value: int) -> tuple[int, int]:
    return value * 2, torch.get_num_threads()


def test_cpu_threads_restores_the_count_also_on_error():
    before = torch.get_num_threads()
    with cpu_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError), cpu_threads(1):
        raise RuntimeError("boom")
    assert torch.get_num_threads() == before
    with cpu_threads(None):
        assert torch.get_num_threads() == before


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_cpu_threads_refuses_bad_counts(bad):
    with pytest.raises(ValueError, match="num_threads"):
        with cpu_threads(bad):
            pass


def test_in_process_pool_runs_with_one_thread_and_restores():
    before = torch.get_num_threads()
    results = dict(run_tasks(_threads_in_worker, [(1,), (2,)], num_workers=1))
    assert results == {(1,): (2, 1), (2,): (4, 1)}
    assert torch.get_num_threads() == before
    pool = worker_pool(1)
    assert pool.submit(_threads_in_worker, 3).result() == (6, 1)
    pool.shutdown()
    assert torch.get_num_threads() == before


def test_spawned_pool_workers_have_one_thread():
    results = dict(run_tasks(_threads_in_worker, [(1,), (2,), (3,)], num_workers=2))
    assert results == {(1,): (2, 1), (2,): (4, 1), (3,): (6, 1)}


def test_task_errors_reach_the_caller():
    with pytest.raises(ZeroDivisionError):
        list(run_tasks(divmod, [(1, 0)], num_workers=1))


def _sleeper(path: str) -> None:
    Path(path).write_text(str(os.getpid()))
    time.sleep(120)


def _pool_then_wait(path: str) -> None:
    """A parent with a 2-worker pool whose task sleeps (run in a subprocess by the test)."""
    pool = worker_pool(2)
    pool.submit(_sleeper, path)
    time.sleep(120)


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")  # a zombie has ended (nobody may reap it in a container)


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
def test_spawned_workers_end_when_their_parent_is_killed(tmp_path):
    """SIGTERM to a process with a pool ends its busy worker within a few seconds."""
    marker = tmp_path / "worker.pid"
    root = Path(__file__).resolve().parents[2]
    code = (f"import sys; sys.path.insert(0, {str(root)!r}); "
            f"from tests.utils.test_threads import _pool_then_wait; "
            f"_pool_then_wait({str(marker)!r})")
    parent = subprocess.Popen([sys.executable, "-c", code])
    try:
        deadline = time.monotonic() + 60
        while not (marker.exists() and marker.read_text()) and time.monotonic() < deadline:
            time.sleep(0.2)
        worker = int(marker.read_text())
        assert _alive(worker)
        parent.send_signal(signal.SIGTERM)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(worker)
    finally:
        parent.kill()
