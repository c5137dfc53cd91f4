"""``lisa eval --quick``: the whole evaluation pipeline at toy sizes, in a few minutes on a CPU.

Without models, it first makes what it needs in ``OUT/quick``: a tiny synthetic dataset
(:func:`lisa_hand.data.synth.dataset.synthesize`: 4 subjects, 2 poses, 5 views of 64 x 48, one
held-out
test subject) and every method trained for a few dozen steps with tiny fields (VolSDF, NASA,
NARF, LISA-im on the images; LISA-geom on the scans; LISA-full from LISA-geom). The numbers
only show that every stage runs and measures in millimetres and dB, not how the methods
compare: that needs the full run of ``docs/results.md``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from .config import EvalConfig

__all__ = ["QUICK_EVAL", "quick_config", "quick_models"]

QUICK_EVAL = EvalConfig(num_subjects=1, num_poses=2, image_subjects=1, views=(1, 4),
                        resolution=48, template_vertices=5_000, fit_scale=0.05,
                        render_samples=8, workers=1)
"""The evaluation's settings in quick mode (the methods and data are the caller's)."""

_TINY_FIELD = dict(sdf_hidden=32, sdf_depth=2, skinning_hidden=32, skinning_depth=1,
                   color_hidden=16, color_depth=1, pe_frequencies=4, shape_dim=8, color_dim=8)
_COMPOSITIONS = {"volsdf": "single", "nasa": "nasa", "narf": "narf", "lisa_im": "lisa",
                 "lisa_full": "lisa"}


def quick_config(**overrides) -> EvalConfig:
    """:data:`QUICK_EVAL` with ``overrides``."""
    return dataclasses.replace(QUICK_EVAL, **overrides)


def quick_models(work: str | Path, steps: int = 30, log: Callable[[str], None] = print
                 ) -> tuple[Path, dict[str, str]]:
    """Synthesize the tiny dataset into ``work/data`` and train every method on it for
    ``steps`` steps into ``work/METHOD``. -> (dataset folder, {method: run folder}).

    Runs that already finished are reused (their ``last.pt`` is resumed, a no-op when done).
    """
    from ..data.synth.dataset import SynthConfig, synthesize
    from ..fields.config import FieldConfig
    from ..render import RenderConfig
    from ..training.config import TrainerConfig
    from ..training.images import ImageTrainConfig, train_images
    from ..training.prior import PriorConfig, train_prior

    work = Path(work)
    data = work / "data"
    if not (data / "split.json").is_file():
        log("quick: synthesizing a tiny dataset (4 subjects x 2 poses x 5 views of 64 x 48)")
        synthesize(data, SynthConfig(num_subjects=4, num_poses=2, num_views=5, resolution=(64, 48),
                                     seed=0, split_fractions=(0.5, 0.25, 0.25),
                                     voxels_per_length=64, num_sdf_samples=2000,
                                     num_workers=1), progress=False, overwrite=True)
    trainer = dict(steps=steps, lr=2e-3, device="cpu", progress=False, print_every=0,
                   checkpoint_every=0, seed=3)
    runs = {"lisa_geom": work / "lisa_geom"}
    log(f"quick: training every method for {steps} steps with tiny fields")
    train_prior(data, runs["lisa_geom"], PriorConfig(
        field=FieldConfig(use_color=False, **_TINY_FIELD), trainer=TrainerConfig(**trainer),
        frames_per_step=2, surface_points=128, space_points=128))
    for method, composition in _COMPOSITIONS.items():
        runs[method] = work / method
        config = ImageTrainConfig(
            field=FieldConfig(composition=composition, **_TINY_FIELD),
            trainer=TrainerConfig(**trainer, find_unused_parameters=True),
            render=RenderConfig(sampler="uniform", num_samples=24, stratified=True),
            num_rays=128, num_frames=2, eikonal_ray_points=16, eikonal_uniform_points=16,
            skinning_points=32, band_px=2, max_band_px=4, background_per_view=256,
            beta_init=0.004)
        train_images(data, runs[method], config,
                     prior=runs["lisa_geom"] if method == "lisa_full" else None)
    order = ["volsdf", "nasa", "narf", "lisa_im", "lisa_geom", "lisa_full"]
    return data, {m: str(runs[m]) for m in order}
