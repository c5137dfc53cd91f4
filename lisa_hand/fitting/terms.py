"""Energy terms as objects: a name, a weight and what the term measures of a batch of hands.

A :class:`Term` reads one input (whatever its energy is about: the hands' pose and codes for the
priors, a posed surface proxy and the cloud for the point fit's proxy terms,
:mod:`lisa_hand.fitting.points.proxy_terms`, field values for its field terms,
:mod:`lisa_hand.fitting.points.field_terms`) and returns one value per candidate, or None where
it does not apply (no input for it: a cloud without normals, without a sensor). An
:class:`Energy` sums the weighted terms that apply.

The priors every fitter shares (the finger-pose prior, the joint limits, the shape code's and
the betas' priors, the one-view coupling of unseen fingers, the hand-size prior) are
:class:`Term` objects over one input, :class:`HandTerms` (the candidates' pose, codes, betas and
joints, each [K, ...]). An :class:`Energy` is a tuple of terms: it sums the weighted terms that
apply (weight above 0, their inputs present) and names each part for the logs. The point fit's
proxy and field stages and the image fitter's keypoint and colour stages build theirs with
:func:`hand_prior` from their settings (``pose_weight``, ``limit_weight``, ``shape_weight``,
``betas_weight``, ...: one name a weight everywhere).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from .priors import finger_coupling, finger_pose_prior, joint_limit_excess, thumb_pose_prior

__all__ = ["HandTerms", "Term", "FingerPosePrior", "JointLimits", "FingerCoupling",
           "UnseenThumb", "ShapeCodePrior", "BetasPrior", "SizePrior", "Energy", "hand_prior"]


@dataclass(frozen=True)
class HandTerms:
    """What the prior terms read of K candidate hands.

    pose: [K, 48] or [K, 45] (finger values only) axis-angle radians. shape_code: [K, D] or
    None (not optimised). betas: [K, B] or None. joints: [K, 16, 3] metres or None (only the
    bone lengths count).
    """

    pose: torch.Tensor
    shape_code: torch.Tensor | None = None
    betas: torch.Tensor | None = None
    joints: torch.Tensor | None = None

    @property
    def count(self) -> int:
        """K, the candidates."""
        return self.pose.shape[0]

    @property
    def device(self) -> torch.device:
        return self.pose.device


@dataclass(frozen=True)
class Term:
    """One energy term: ``weight`` times :meth:`value`; ``name`` labels it in the logs."""

    name: str
    weight: float

    def value(self, inputs: Any) -> torch.Tensor | None:
        """[K] the unweighted term of the input's K candidates, or None where it does not
        apply."""
        raise NotImplementedError


@dataclass(frozen=True)
class FingerPosePrior(Term):
    """Mean squared difference of the finger values from ``mean_fingers`` [45] radians
    (:func:`lisa_hand.fitting.priors.finger_pose_prior`), radians^2."""

    mean_fingers: torch.Tensor = None

    def value(self, hands: HandTerms) -> torch.Tensor:
        return finger_pose_prior(hands.pose, self.mean_fingers)


@dataclass(frozen=True)
class JointLimits(Term):
    """Squared excess of the finger joints' anatomical angles over their limits
    (:func:`lisa_hand.fitting.priors.joint_limit_excess`), radians^2."""

    def value(self, hands: HandTerms) -> torch.Tensor:
        return joint_limit_excess(hands.pose)


@dataclass(frozen=True)
class FingerCoupling(Term):
    """The flexion of unseen fingers pulled toward their neighbours', weighted per finger by
    ``fingers`` [4] (:func:`lisa_hand.fitting.priors.finger_coupling`), radians^2."""

    fingers: torch.Tensor = None

    def value(self, hands: HandTerms) -> torch.Tensor:
        return finger_coupling(hands.pose, self.fingers)


@dataclass(frozen=True)
class UnseenThumb(Term):
    """An unseen thumb's pull toward ``mean_fingers``, times how unseen it is (``thumb``, 0-1;
    :func:`lisa_hand.fitting.priors.thumb_pose_prior`), radians^2."""

    thumb: torch.Tensor = None
    mean_fingers: torch.Tensor = None

    def value(self, hands: HandTerms) -> torch.Tensor:
        return self.thumb * thumb_pose_prior(hands.pose, self.mean_fingers)


@dataclass(frozen=True)
class ShapeCodePrior(Term):
    """Mean square of the shape code in units of ``scale`` (the training codes' root mean
    square entry), so that a training subject's code costs about the weight."""

    scale: float = 1.0

    def value(self, hands: HandTerms) -> torch.Tensor | None:
        if hands.shape_code is None:
            return None
        code = hands.shape_code / self.scale
        return (code * code).mean(-1)


@dataclass(frozen=True)
class BetasPrior(Term):
    """Mean square of the template's shape coefficients (betas ~ N(0, 1) over subjects)."""

    def value(self, hands: HandTerms) -> torch.Tensor | None:
        if hands.betas is None:
            return None
        return (hands.betas * hands.betas).mean(-1)


@dataclass(frozen=True)
class SizePrior(Term):
    """The hand's size against the training subjects'
    (:class:`lisa_hand.fitting.images.shape_prior.HandSizePrior`: squared standard scores)."""

    prior: Any = None

    def value(self, hands: HandTerms) -> torch.Tensor | None:
        if hands.joints is None or self.prior is None:
            return None
        return self.prior.energy(hands.joints)


@dataclass(frozen=True)
class Energy:
    """A sum of weighted terms over one kind of input (which has a ``count`` of candidates and
    the ``device`` they are on)."""

    terms: tuple[Term, ...]

    def parts(self, inputs: Any) -> dict[str, torch.Tensor]:
        """{name: [K] weighted term} of the terms that apply (weight above 0, input present),
        in order."""
        parts = {}
        for term in self.terms:
            if term.weight > 0:
                value = term.value(inputs)
                if value is not None:
                    parts[term.name] = value if term.weight == 1.0 else term.weight * value
        return parts

    def __call__(self, inputs: Any) -> torch.Tensor:
        """[K] the energy: the sum of :meth:`parts` in order (zeros when none applies)."""
        total = None
        for value in self.parts(inputs).values():
            total = value if total is None else total + value
        return torch.zeros(inputs.count, device=inputs.device) if total is None else total


def hand_prior(config, mean_fingers: torch.Tensor, *, shape_scale: float | None = None,
               coupling: torch.Tensor | None = None, size_prior: Any = None) -> Energy:
    """The prior of a fitter's stage from its settings: ``config.pose_weight`` x the finger-pose
    prior toward ``mean_fingers`` [45], ``config.limit_weight`` x the joint limits,
    ``config.betas_weight`` x the betas' prior; with ``shape_scale``, ``config.shape_weight``
    x the shape code's prior; with ``coupling`` ([5] weights of the unseen fingers of
    :data:`~lisa_hand.fitting.priors.UNSEEN_FINGERS`), ``config.coupling_weight`` x their
    coupling and ``config.unseen_thumb_weight`` x the unseen thumb's pull; with
    ``size_prior``, ``config.size_weight`` x the size prior."""
    terms: list[Term] = [FingerPosePrior("pose", config.pose_weight, mean_fingers)]
    if coupling is not None:
        terms += [FingerCoupling("coupling", config.coupling_weight, coupling[:4]),
                  UnseenThumb("unseen_thumb", config.unseen_thumb_weight, coupling[4],
                              mean_fingers)]
    terms.append(JointLimits("limits", config.limit_weight))
    if shape_scale is not None:
        terms.append(ShapeCodePrior("shape", config.shape_weight, shape_scale))
    terms.append(BetasPrior("betas", config.betas_weight))
    if size_prior is not None:
        terms.append(SizePrior("size", config.size_weight, size_prior))
    return Energy(tuple(terms))
