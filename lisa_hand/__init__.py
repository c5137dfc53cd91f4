"""LISA-open: Learning Implicit Shape and Appearance of hands (Corona et al., CVPR 2022).

The pipeline, one folder a layer: ``utils`` -> ``geometry`` -> ``skeleton`` -> ``handmodel``/``data`` ->
``fields`` -> ``render`` -> ``training`` -> ``fitting``/``meshing`` -> ``evaluation`` -> ``cli``.
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
