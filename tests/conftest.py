"""Fixtures shared by several test folders."""

from __future__ import annotations

import pytest

from lisa_hand.utils.threads import cpu_threads


@pytest.fixture
def one_thread():
    """Torch on one CPU thread during the test (the CI machine's 2 cores are shared by the
    test process and the fits' workers), restored afterwards."""
    with cpu_threads(1):
        yield


@pytest.fixture(scope="module")
def one_thread_per_module():
    """:func:`one_thread` for a whole test module, its module-scoped fixtures (scenes, fits)
    included: ``pytestmark = pytest.mark.usefixtures("one_thread_per_module")``."""
    with cpu_threads(1):
        yield
