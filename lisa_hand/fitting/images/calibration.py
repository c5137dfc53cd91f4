"""The input cameras' colour response, fitted beside the colour code (:class:`ViewCalibration`).

LISA calibrates every training camera with a per-channel gain and bias (Section 4.2, after
Neural Volumes) and renders a new hand with their mean. The cameras of a fit are not training
cameras: each has its own response, and with the mean calibration alone the colour code
absorbs the input views' responses: a few views whose average response is, say, bluer than
neutral pull the code, whose decoder makes skin colours only, towards a greyer, less red skin,
and the novel views (rendered without those responses) come out with the wrong colour.

Each view ``v`` gets the response

    gain_v = gain * (1 + view_gain_std * z_gain[v]),   bias_v = bias + view_bias_std * z_bias[v]

(``gain``, ``bias`` [3]: the model's mean calibration; ``z`` [V, 3] unknowns in standard
deviations of the cameras' spread, starting at 0) with the Gaussian prior
``0.5 * mean_v |z[v]|^2`` (both tables). The colour code keeps the skin colour every view shares;
what one view has in excess of the others, and a shift no skin colour explains, goes to
``z``. The fitted hand is then rendered, as in the paper, with the model's mean calibration.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

__all__ = ["ViewCalibration"]


class ViewCalibration:
    """Per-view relative gain and bias of the colour stage (see the module docstring).

    num_views: V. gain_std, bias_std: the spread of the cameras' gains (unitless) and biases
    (colour units, [0, 1] scale) the unknowns are measured in. enabled: False keeps ``z = 0``
    (the model's mean calibration for every view). device: of the unknowns.
    """

    def __init__(self, num_views: int, gain_std: float, bias_std: float, enabled: bool,
                 device: torch.device) -> None:
        if num_views < 1:
            raise ValueError(f"num_views must be >= 1, got {num_views}")
        for name, value in (("gain_std", gain_std), ("bias_std", bias_std)):
            if not value >= 0:
                raise ValueError(f"{name} must be >= 0, got {value!r}")
        self.enabled = bool(enabled) and (gain_std > 0 or bias_std > 0)
        self.gain_std, self.bias_std = float(gain_std), float(bias_std)
        self.z_gain = torch.zeros(num_views, 3, device=device, requires_grad=self.enabled)
        self.z_bias = torch.zeros(num_views, 3, device=device, requires_grad=self.enabled)

    def parameters(self) -> list[torch.Tensor]:
        """The unknowns to optimise ([] when disabled)."""
        return [self.z_gain, self.z_bias] if self.enabled else []

    def gains_biases(self, gain: torch.Tensor, bias: torch.Tensor
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """gain, bias [3]: the mean calibration -> per-view gain [V, 3], bias [V, 3]."""
        return (gain * (1.0 + self.gain_std * self.z_gain),
                bias + self.bias_std * self.z_bias)

    def for_rays(self, gain: torch.Tensor, bias: torch.Tensor, view: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor]:
        """gain, bias [3]; view [R] index of each ray's view -> gain [R, 3], bias [R, 3]."""
        gains, biases = self.gains_biases(gain, bias)
        return gains[view], biases[view]

    def prior(self) -> torch.Tensor:
        """``0.5 * mean_v (|z_gain[v]|^2 + |z_bias[v]|^2)`` (0 when disabled)."""
        if not self.enabled:
            return self.z_gain.new_zeros(())
        return 0.5 * ((self.z_gain**2).sum(-1) + (self.z_bias**2).sum(-1)).mean()

    @torch.no_grad()
    def to_dict(self, names: Sequence[str], gain: torch.Tensor, bias: torch.Tensor
                ) -> dict[str, dict[str, list[float]]]:
        """{view name: {"gain": [3], "bias": [3]}}: the fitted responses, JSON-ready."""
        gains, biases = self.gains_biases(gain, bias)
        return {name: {"gain": [float(v) for v in gains[i]], "bias": [float(v) for v in biases[i]]}
                for i, name in enumerate(names)}
