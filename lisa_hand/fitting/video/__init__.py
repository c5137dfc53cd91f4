"""Fitting hands through a video clip (``lisa fit-video``): :func:`fit_video` (the fit),
:func:`fit_video_folder` (the fit and its files), :class:`FitVideoConfig` (its settings)."""

from .config import FitVideoConfig, MotionConfig
from .fit import VideoFit, fit_video
from .io import VideoFitReport, fit_video_folder

__all__ = ["FitVideoConfig", "MotionConfig", "VideoFit", "fit_video", "VideoFitReport",
           "fit_video_folder"]
