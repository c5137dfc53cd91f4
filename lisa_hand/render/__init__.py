"""VolSDF volume rendering (LISA Section 4.1, "Model rendering") and whole images of a field.

Field functions come in as callbacks (the protocol of :mod:`lisa_hand.geometry.fields`, re-exported
here); this package never imports the model. Pieces: the Laplace density (:mod:`.density`),
sample placement (:mod:`.samplers`), the compositing quadrature (:mod:`.composite`), the chunked
ray renderer plus colour calibration (:mod:`.renderer`), empty-space skipping (:mod:`.occupancy`),
whole images (:mod:`.image`), saving them (:mod:`.saving`) and many views (:mod:`.turntable`).
Meshes are ray cast by :mod:`.raycast` (not re-exported here; the ground-truth images and scans
of :mod:`lisa_hand.data` use it).
Ray bounds, the sphere tracer and SDF normals live one layer down, in
:mod:`lisa_hand.geometry.rays` and :mod:`lisa_hand.geometry.tracing` (the data generator uses them
too).
"""

from ..geometry.fields import FieldFn, NormalFn, SdfFn, call_field, call_sdf
from ..geometry.rays import ray_box_bounds, ray_sphere_bounds
from ..geometry.tracing import SurfaceHits, sdf_normals, sphere_trace
from .composite import RenderOutput, composite, sample_deltas
from .density import LaplaceDensity, laplace_cdf, volsdf_density
from .image import ImageOutput, ImageRenderConfig, grid_threshold, render_image
from .occupancy import OccupancyGrid, build_occupancy_grid
from .renderer import (
    SAMPLERS,
    RenderConfig,
    apply_gain_bias,
    calibrate,
    place_samples,
    render_rays,
)
from .samplers import (
    ErrorBoundedSamples,
    distance_lower_bound,
    error_bounded_samples,
    error_bounded_sampling,
    opacity_error_bound,
    uniform_samples,
)
from .saving import image_to_uint8, normals_to_rgb, save_image_outputs
from .sphere_tracing import sphere_traced_samples
from .turntable import orbit_cameras, render_turntable, save_gif, save_video, shared_grid

__all__ = [
    "FieldFn",
    "NormalFn",
    "SdfFn",
    "call_field",
    "call_sdf",
    "ray_box_bounds",
    "ray_sphere_bounds",
    "SurfaceHits",
    "sdf_normals",
    "sphere_trace",
    "RenderOutput",
    "composite",
    "sample_deltas",
    "LaplaceDensity",
    "laplace_cdf",
    "volsdf_density",
    "ImageOutput",
    "ImageRenderConfig",
    "grid_threshold",
    "render_image",
    "OccupancyGrid",
    "build_occupancy_grid",
    "SAMPLERS",
    "RenderConfig",
    "apply_gain_bias",
    "calibrate",
    "place_samples",
    "render_rays",
    "ErrorBoundedSamples",
    "error_bounded_sampling",
    "error_bounded_samples",
    "opacity_error_bound",
    "distance_lower_bound",
    "sphere_traced_samples",
    "uniform_samples",
    "image_to_uint8",
    "normals_to_rgb",
    "save_image_outputs",
    "orbit_cameras",
    "render_turntable",
    "save_gif",
    "save_video",
    "shared_grid",
]
