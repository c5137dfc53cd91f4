"""The hand's size, searched on the proxy ('size', no network), before the fingers.

The proxy stages (:mod:`lisa_hand.fitting.points.proxy`) pose the model's mean hand on the
template's mean skeleton, and only the field stage fits the skeleton (the template's betas). A
hand much larger or smaller than the mean is then aligned and posed as a mean-sized hand:
its fingers' joints land millimetres off, and the field stage, starting there, takes the
skeleton only part of the way, the shape code making up the rest, and the fit ends farther
from the scan than one started at the hand's true size.

:func:`search_size` tries the best candidate at each size of ``FitPointsConfig.sizes`` (the
mean skeleton and proxy scaled about the wrist, a few Adam steps of its pose on the proxy
energy each), keeps the size of lowest proxy energy, and hands every candidate on at that
size: the proxy scaled, their skeletons the template's for the betas nearest that size
(:func:`betas_for_size`), which the field stage starts from. When the mean size wins, the
candidates go on untouched, and either way the cloud's random stream is left where it was, so
such a fit is the fit without the search.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import torch

from ...skeleton.params import HandParams
from ..stages import StageReport
from .candidates import CandidateBatch
from .cloud import TargetCloud
from .monitor import FitMonitor
from .proxy import SurfaceProxy, optimise_on_proxy, proxy_energy

__all__ = ["betas_for_size", "scaled_proxy", "search_size"]

_MM = 1e-3
_SCORE_POINTS = 2048  # cloud points each size is scored on (the same ones for every size)


@torch.no_grad()
def betas_for_size(template, size: float, ridge: float = 1e-5) -> torch.Tensor:
    """[K] the template's betas whose rest skeleton is nearest (least squares, a small ridge
    ``ridge`` on the betas, in metres^2 per unit beta^2) to its mean skeleton scaled by
    ``size`` about the wrist joint: the betas of a hand ``size`` times the mean one. The
    skeleton is linear in the betas, so this is one ridge solve."""
    zero = torch.zeros(1, template.num_betas, dtype=torch.float64)
    mean = template.rest_joints(zero.to(template.v_template))[0].double()
    basis = template.rest_joints(torch.eye(template.num_betas).to(template.v_template)).double()
    directions = (basis - mean).reshape(template.num_betas, -1).T  # [48, K] per unit beta
    target = (mean[0] + size * (mean - mean[0]) - mean).reshape(-1)
    normal = directions.T @ directions + ridge * torch.eye(template.num_betas, dtype=torch.float64)
    return torch.linalg.solve(normal, directions.T @ target).float()


def scaled_proxy(proxy: SurfaceProxy, size: float, rest_joints: torch.Tensor) -> SurfaceProxy:
    """The proxy ``size`` times larger about its wrist joint, moved onto the skeleton
    ``rest_joints`` [16, 3] metres (whose wrist the scaled wrist lands on); the normals and
    skinning weights unchanged."""
    wrist = proxy.rest_joints[0]

    def move(points: torch.Tensor) -> torch.Tensor:
        return rest_joints[0] + size * (points - wrist)

    return SurfaceProxy(move(proxy.points_rest), proxy.weights, rest_joints,
                        move(proxy.pivot), proxy.normals_rest)


def _resized(hands: Sequence[HandParams], pivot: torch.Tensor, proxy: SurfaceProxy,
             betas: torch.Tensor) -> list[HandParams]:
    """``hands`` (on the proxy of pivot ``pivot`` [3] metres) on the resized ``proxy``: the
    same rotation, finger pose and world position of the pivot, the new skeleton and betas."""
    if not hands:
        return []
    batch = CandidateBatch.from_hands(hands, pivot)
    moved = CandidateBatch(batch.rotation().detach(), batch.position.detach(),
                           batch.finger_pose.detach(), batch.shape_code.detach(),
                           pivot=proxy.pivot,
                           rest_joints=proxy.rest_joints.expand(batch.count, -1, -1))
    return [moved.hand(index, dataclasses.replace(hand, betas=betas.cpu().float()))
            for index, hand in enumerate(hands)]


def _score(proxy: SurfaceProxy, cloud: TargetCloud, batch: CandidateBatch, config,
           state: torch.Tensor) -> float:
    """Proxy energy of the batch's first candidate at the final robust scale, on the same
    cloud points for every size (the generator reset to ``state``)."""
    cloud.generator.set_state(state)
    with torch.no_grad():
        return float(proxy_energy(proxy, cloud, batch, config, config.robust_scale_mm * _MM,
                                  num_points=_SCORE_POINTS)[0])


def search_size(proxy: SurfaceProxy, cloud: TargetCloud, candidates: Sequence[HandParams],
                template, config, *, monitor: FitMonitor | None = None
                ) -> tuple[SurfaceProxy, list[HandParams], StageReport]:
    """The size search ('size', no network) of the module docstring.

    proxy: the mean hand's proxy, on the template's mean skeleton; candidates: right hands on
    that skeleton (the pose stage's, best first); template: the mesh template whose betas give
    the skeleton (None, a fixed skeleton: nothing searched). config: a
    :class:`~lisa_hand.fitting.points.config.FitPointsConfig` (``sizes``, ``size_iters``;
    nothing searched with ``fit_betas`` False, which keeps the mean skeleton).
    -> (the proxy at the chosen size, the candidates on it with its betas, the
    :class:`StageReport` ('size'): ``screened_energies`` the best candidate's proxy energy at
    each size, ``loss`` the chosen one's, ``notes`` the size chosen).
    """
    start = time.perf_counter()
    began = len(monitor.history) if monitor is not None else 0
    sizes = tuple(config.sizes)
    if template is None or not config.fit_betas or len(sizes) < 2:
        return proxy, list(candidates), StageReport(stage="size", seconds=0.0)
    state = cloud.generator.get_state()
    like = dict(device=proxy.pivot.device, dtype=proxy.pivot.dtype)
    energies, options = [], []
    for size in sizes:
        betas = betas_for_size(template, size).to(**like)
        sized = scaled_proxy(proxy, size, template.rest_joints(betas[None])[0].to(**like))
        best = _resized(candidates[:1], proxy.pivot, sized, betas)
        batch = CandidateBatch.from_hands(best, sized.pivot)
        if config.size_iters > 0:
            optimise_on_proxy(sized, cloud, batch, config, "size", config.size_iters,
                              like=best[0], monitor=monitor)
        energies.append(_score(sized, cloud, batch, config, state))
        options.append((size, betas, sized, batch.hand(0, best[0])))
    cloud.generator.set_state(state)  # the later stages draw as they would without the search
    chosen = min(range(len(sizes)), key=energies.__getitem__)
    size, betas, sized, posed = options[chosen]
    if size == 1.0:  # the mean size: the candidates go on exactly as they came
        sized, hands = proxy, list(candidates)
    else:
        hands = [posed] + _resized(candidates[1:], proxy.pivot, sized, betas)
    history = monitor.history[began:] if monitor is not None else []
    return sized, hands, StageReport(
        stage="size", seconds=time.perf_counter() - start, loss=energies[chosen],
        screened_energies=energies, history=history,
        notes=[f"hand size {size:g} times the mean skeleton"])
