"""What the training subjects say about an unseen hand's shape, for the image fit.

* :class:`ShapeSpace`: the principal subspace of the training subjects' shape codes ``beta+``
  (the rows of ``TrainedModel.shape_codes``). The colour stage optimises the coefficients ``c``
  of the top principal directions, in standard deviations,
  ``beta+ = mean + offset + sum_i c_i std_i u_i``, clamped after every step to the training
  codes' range along each direction (``low``, ``high``: about +-1.5-2.2 std for the shipped
  model's 21 subjects), with the Gaussian prior ``0.5 |c|^2`` (the Mahalanobis distance of the
  code to the training codes' mean, squared, halved). A code outside this space is one the
  decoder never saw: on real photos the colour loss can push a free code several times further
  from the mean than any training subject, and the surface breaks into lumps and floaters.
  The range matters too: along the shipped model's first direction (the flesh: -1 std is
  +10 % of surface area) a hand at +3 std falls apart into pieces, at the training range's
  end it is whole.
* :class:`HandSizePrior`: the hand's size (:func:`hand_size`, the summed length of the 15 bones
  of the rest skeleton, metres) over the training subjects: the template's betas are
  unit-variance principal coefficients of the open hand's subjects (the population the training
  subjects are drawn from, :mod:`lisa_hand.handmodel.template_build`), so the sizes of
  ``template.rest_joints(betas)`` for ``betas ~ N(0, I)`` are their sizes (shipped template:
  0.725 m +- 0.045 m, 6.1 %). One view cannot tell a large hand far away from a small one
  nearby; with this prior the depth follows from the keypoints' pixel size and the focal length.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import torch

from ...skeleton.tree import NUM_KEYPOINTS, PARENTS

__all__ = ["ShapeSpace", "hand_size", "HandSizePrior"]

_RANK_TOLERANCE = 1e-4
"""Principal directions whose standard deviation is below this fraction of the first one's are
dropped (S codes span at most S - 1 directions)."""
_SIZE_SAMPLES = 1024
_SIZE_SEED = 0


@dataclass(frozen=True)
class ShapeSpace:
    """The principal subspace of a set of shape codes.

    mean: [D] the codes' mean. directions: [k, D] orthonormal principal directions, largest
    variance first. std: [k] the codes' standard deviation along each (unbiased, > 0).
    low, high: [k] the smallest and largest coefficient (standard deviations) of the codes
    along each direction.
    """

    mean: torch.Tensor
    directions: torch.Tensor
    std: torch.Tensor
    low: torch.Tensor
    high: torch.Tensor

    @classmethod
    def from_codes(cls, codes: torch.Tensor, max_dims: int | None = None) -> ShapeSpace:
        """The principal subspace of ``codes`` [S, D] (S >= 2): at most ``max_dims`` directions
        (None: all of them, at most S - 1), those with a non-negligible spread."""
        if codes.ndim != 2 or codes.shape[0] < 2:
            raise ValueError(f"the shape space needs >= 2 training codes [S, D], got "
                             f"{list(codes.shape)}")
        codes = codes.detach().double()
        mean = codes.mean(0)
        _, singular, right = torch.linalg.svd(codes - mean, full_matrices=False)
        std = singular / (codes.shape[0] - 1) ** 0.5
        keep = int((std > _RANK_TOLERANCE * std[0]).sum()) if std[0] > 0 else 0
        if max_dims is not None:
            keep = min(keep, int(max_dims))
        directions, std = right[:keep], std[:keep]
        coefficients = (codes - mean) @ directions.T / std  # [S, k]
        return cls(mean=mean.float(), directions=directions.float(), std=std.float(),
                   low=coefficients.amin(0).float(), high=coefficients.amax(0).float())

    @property
    def num_dims(self) -> int:
        return int(self.std.numel())

    def to(self, device: torch.device | str) -> ShapeSpace:
        return ShapeSpace(*(value.to(device) for value in (self.mean, self.directions, self.std,
                                                           self.low, self.high)))

    def clamp(self, coefficients: torch.Tensor, margin: float = 0.0) -> torch.Tensor:
        """coefficients [..., k] clamped to ``[low - margin, high + margin]`` (standard
        deviations)."""
        return torch.maximum(torch.minimum(coefficients, self.high + margin), self.low - margin)

    def split(self, code: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """code [D] -> (coefficients [k] in standard deviations, offset [D]: the part of
        ``code - mean`` outside the subspace); :meth:`code` puts them back together."""
        centred = code.to(self.mean) - self.mean
        projected = self.directions @ centred
        offset = centred - self.directions.T @ projected
        return projected / self.std, offset

    def code(self, coefficients: torch.Tensor, offset: torch.Tensor | None = None
             ) -> torch.Tensor:
        """coefficients [..., k] (standard deviations) -> codes [..., D]."""
        code = self.mean + (coefficients * self.std) @ self.directions
        return code if offset is None else code + offset

    def mahalanobis(self, code: torch.Tensor) -> float:
        """Distance of ``code`` [D] to the mean in standard deviations, within the subspace."""
        coefficients, _ = self.split(code)
        return float(coefficients.norm())


def hand_size(rest_joints: torch.Tensor) -> torch.Tensor:
    """Summed length of the 15 bones (joint to parent) of rest skeletons: [B, 16, 3] metres ->
    [B] metres."""
    parents = list(PARENTS[1:])
    return (rest_joints[:, 1:] - rest_joints[:, parents]).norm(dim=-1).sum(-1)


@dataclass(frozen=True)
class HandSizePrior:
    """The training subjects' hand size (see the module docstring).

    mean_m, std_m: mean and standard deviation of :func:`hand_size`, metres.
    keypoint_scale: :meth:`energy`'s factor, ``21 / n`` for ``n`` visible keypoints over all
        views (:meth:`for_keypoints`): the keypoint loss is a mean over the keypoints, so with
        this factor the prior counts as one view's worth of keypoints whatever their number
        (a Gaussian prior beside a Laplace likelihood summed over the keypoints).
    """

    mean_m: float
    std_m: float
    keypoint_scale: float = 1.0

    @classmethod
    def from_template(cls, template: Any) -> HandSizePrior:
        """The sizes of ``template.rest_joints(betas)`` for 1024 seeded ``betas ~ N(0, I)``."""
        generator = torch.Generator().manual_seed(_SIZE_SEED)
        betas = torch.randn(_SIZE_SAMPLES, int(template.num_betas), generator=generator,
                            dtype=torch.float64)
        with torch.no_grad():
            joints = template.rest_joints(betas.to(template.device, template.dtype))
            sizes = hand_size(joints.double())
        return cls(mean_m=float(sizes.mean()), std_m=float(sizes.std()))

    def for_keypoints(self, num_visible: float) -> HandSizePrior:
        """This prior with ``keypoint_scale = 21 / num_visible`` (1 without keypoints)."""
        scale = NUM_KEYPOINTS / num_visible if num_visible > 0 else 1.0
        return replace(self, keypoint_scale=float(scale))

    def energy(self, rest_joints: torch.Tensor) -> torch.Tensor:
        """``keypoint_scale * ((hand_size - mean_m) / std_m)^2``: rest_joints [B, 16, 3] metres
        (posed joints give the same: only bone lengths count) -> [B]."""
        z_score = (hand_size(rest_joints) - self.mean_m) / self.std_m
        return self.keypoint_scale * z_score**2
