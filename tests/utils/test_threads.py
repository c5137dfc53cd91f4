"""cpu_threads and the worker pool: the thread count is set for a block and given back."""

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
