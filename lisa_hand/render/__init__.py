"""VolSDF volume rendering (LISA Section 4.1, "Model rendering").

Field functions come in as callbacks; this package never imports the model. Pieces: the Laplace
density (:mod:`.density`), near/far bounds from a bounding sphere (:mod:`.bounds`), sample
placement (:mod:`.samplers`), the compositing quadrature (:mod:`.composite`) and the chunked
renderer plus colour calibration (:mod:`.renderer`).
"""

from .bounds import ray_sphere_bounds
from .composite import RenderOutput, composite, sample_deltas
from .density import LaplaceDensity, laplace_cdf, volsdf_density
from .renderer import SAMPLERS, FieldFn, RenderConfig, apply_gain_bias, calibrate, render_rays
from .samplers import (
    ErrorBoundedSamples,
    SdfFn,
    distance_lower_bound,
    error_bounded_samples,
    error_bounded_sampling,
    opacity_error_bound,
    sphere_traced_samples,
    uniform_samples,
)

__all__ = [
    "ray_sphere_bounds",
    "RenderOutput",
    "composite",
    "sample_deltas",
    "LaplaceDensity",
    "laplace_cdf",
    "volsdf_density",
    "SAMPLERS",
    "FieldFn",
    "RenderConfig",
    "apply_gain_bias",
    "calibrate",
    "render_rays",
    "ErrorBoundedSamples",
    "SdfFn",
    "error_bounded_sampling",
    "error_bounded_samples",
    "opacity_error_bound",
    "distance_lower_bound",
    "sphere_traced_samples",
    "uniform_samples",
]
