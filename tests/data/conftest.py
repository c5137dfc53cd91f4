"""Fixtures of the data tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def mediapipe():
    """MediaPipe, or a skip when the photo extra is missing (or its import fails)."""
    try:
        import mediapipe
    except ImportError as exc:
        pytest.skip(f"the photo extra (pip install -e '.[photo]') is not installed: {exc}")
    return mediapipe
