"""Per-finger restarts of the point fit ('fingers', no network): a finger left bent the wrong way
is a local minimum of the articulated stage that the surface stage does not leave (on hands the
generator did not make, the largest errors are such pose failures: an extended finger left bent,
a thumb in the wrong pose).

After the articulated proxy stage (:func:`lisa_hand.fitting.points.proxy.fit_proxy_pose`), the
best candidate is copied once per finger and start of :data:`FINGER_STARTS` with that finger's
three joints set to the start's (straight, slightly bent, half curled, curled; the thumb, whose
base has the widest range, also from the opposed thumb of "ok"); the copies and the candidate
itself are optimised together on the proxy (rotation, translation and finger pose,
``config.finger_iters`` steps), then scored
on one common subset of the cloud at the final robust scale, prior included. Each finger then
takes its chain from the lowest-scoring of its copies (or keeps the candidate's), and the hand so
combined replaces the last of the candidates when it scores lower than the best one did.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import torch

from ...skeleton import FINGER_JOINTS, FINGER_NAMES
from ...skeleton.params import HandParams
from ..priors import prior_mean_fingers
from ..stages import StageReport
from ..terms import hand_prior
from .candidates import CandidateBatch
from .cloud import TargetCloud
from .monitor import FitMonitor
from .proxy import SurfaceProxy, optimise_on_proxy, proxy_energy

__all__ = ["FINGER_STARTS", "THUMB_STARTS", "restart_fingers"]

FINGER_STARTS = ("flat", "relaxed", "pinch", "fist")
"""Named poses (:func:`lisa_hand.handmodel.poses.named_pose`) each finger restarts from.
"pinch" (the fingers half curled, about 0.6 / 0.95 / 0.8 rad) covers the bend between "relaxed"
and "fist", which neither of them reaches on the proxy from one side (checked by
``python -m benchmarks fit``)."""
THUMB_STARTS = FINGER_STARTS + ("ok",)
"""The thumb's starts."""
_MM = 1e-3
_SCORE_POINTS = 2048  # cloud points of the final comparison (the iterations use 256)


def _slots(finger: str) -> list[int]:
    """Indices of a finger's three joints in the 45 finger values."""
    return [3 * (joint - 1) + axis for joint in FINGER_JOINTS[finger] for axis in range(3)]


def _copies(hand: HandParams) -> tuple[list[HandParams], list[str]]:
    """``hand`` and one copy per finger and start (its chain set to the start's) -> (hands,
    the finger each one restarts, "" for ``hand`` itself)."""
    from ...handmodel.poses import named_pose

    hands, fingers = [hand], [""]
    for finger in FINGER_NAMES:
        slots = [3 + slot for slot in _slots(finger)]
        for name in THUMB_STARTS if finger == "thumb" else FINGER_STARTS:
            pose = hand.pose.clone()
            pose[slots] = named_pose(name)[slots].to(pose)
            hands.append(replace(hand, pose=pose, extra={}))
            fingers.append(finger)
    return hands, fingers


@torch.no_grad()
def _scores(proxy: SurfaceProxy, cloud: TargetCloud, batch: CandidateBatch, config,
            unseen: torch.Tensor | None = None) -> torch.Tensor:
    """[K] proxy energy at the final robust scale on one common cloud subset of
    :data:`_SCORE_POINTS`, plus the prior (with the ``unseen`` fingers' weights)."""
    mean_fingers = prior_mean_fingers(config.prior_pose, batch.pivot.device, batch.pivot.dtype)
    energy = proxy_energy(proxy, cloud, batch, config, config.robust_scale_mm * _MM,
                          num_points=_SCORE_POINTS)
    return energy + hand_prior(config, mean_fingers, coupling=unseen)(batch.terms())


def restart_fingers(proxy: SurfaceProxy, cloud: TargetCloud, candidates: Sequence[HandParams],
                    config, *, monitor: FitMonitor | None = None, moved_base: bool = False,
                    unseen: torch.Tensor | None = None) -> tuple[list[HandParams], StageReport]:
    """The per-finger restarts (see the module docstring).

    candidates: right hands on the proxy's skeleton, best first (the articulated stage's).
    config: a :class:`~lisa_hand.fitting.points.config.FitPointsConfig` (``finger_iters``; 0
    returns the candidates unchanged). moved_base: when no finger changes, return the best
    candidate as optimised with the copies (instead of as it came), so that the caller can
    compare it (the second pass of a one-view scan: the free-space term moves it). unseen: [5]
    weights of the fingers a one-view sensor could not see (:func:`.proxy.unseen_fingers`), or
    None. -> (the candidates, the last replaced by the combined hand when it scores lower; the
    :class:`StageReport` ('fingers'): ``energies`` [the best candidate's score, the combined
    hand's], ``loss`` the lower, and ``changed`` in ``notes``: the fingers that moved).
    """
    start = time.perf_counter()
    candidates = list(candidates)
    began = len(monitor.history) if monitor is not None else 0
    if config.finger_iters == 0 or not candidates:
        return candidates, StageReport(stage="fingers", seconds=0.0)
    hands, fingers = _copies(candidates[0])
    batch = CandidateBatch.from_hands(hands, proxy.pivot)
    optimise_on_proxy(proxy, cloud, batch, config, "fingers", config.finger_iters,
                      like=candidates[0], monitor=monitor, unseen=unseen)
    moved = [batch.hand(index, hands[index]) for index in range(batch.count)]
    scores = _scores(proxy, cloud, batch, config, unseen)
    combined = moved[0].pose.clone()
    changed = []
    for finger in FINGER_NAMES:
        rows = [0] + [index for index, name in enumerate(fingers) if name == finger]
        best = rows[int(scores[rows].argmin())]
        if best != 0:
            slots = [3 + slot for slot in _slots(finger)]
            combined[slots] = moved[best].pose[slots]
            changed.append(finger)
    hand = replace(moved[0], pose=combined, extra={})
    result = candidates
    if moved_base and not changed:
        result = [moved[0]] + candidates[1:]
    energies = [float(scores[0])]
    if changed:
        check = CandidateBatch.from_hands([moved[0], hand], proxy.pivot)
        before, after = (float(v) for v in _scores(proxy, cloud, check, config, unseen))
        energies = [before, after]
        if after < before:
            result = [hand] + candidates[:-1] if len(candidates) > 1 else [hand]
    history = monitor.history[began:] if monitor is not None else []
    return result, StageReport(stage="fingers", seconds=time.perf_counter() - start,
                               loss=min(energies), energies=energies, history=history,
                               notes=[f"restarted: {', '.join(changed) or 'none'}"])
