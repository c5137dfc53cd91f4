"""Real data the tests read, kept in the repository so that they run in any clean clone: the
WebXR hand (MIT), two real photos (Apache-2.0) and a rendered photo of two hands; each
folder's README.md gives source, licence and copyright."""

from __future__ import annotations

from pathlib import Path

ASSETS = Path(__file__).resolve().parent
WEBXR_HAND = ASSETS / "webxr_hand"
"""The artist-made WebXR hand: right_hand.npz, right_hand.obj, left_hand.npz."""
PHOTOS = ASSETS / "photos"
"""hand_thumb_up.jpg and thumbs-up.png."""
TWO_HANDS = ASSETS / "two_hands"
"""holding_wrist.jpg (rendered, one hand behind the other) and its true keypoints."""
