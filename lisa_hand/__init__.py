"""LISA-open: Learning Implicit Shape and Appearance of hands (Corona et al., CVPR 2022).

The pipeline, one folder a layer (imports flow left to right only): ``utils`` -> ``geometry`` ->
``skeleton`` -> ``handmodel``/``data`` -> ``fields`` -> ``model`` -> ``render`` ->
``training``/``fitting``/``inference`` -> ``evaluation`` -> ``bench``/``cli``. The map is
``docs/architecture.md``.
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
