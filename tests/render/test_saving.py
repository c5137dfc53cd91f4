"""Saved image outputs: PNG colours, normal maps, masks and depth."""

import math

import numpy as np
import torch

from lisa_hand.render.saving import normals_to_rgb, save_image_outputs

from .image_scene import render_sphere


def test_saved_outputs_encode_normals(tmp_path):
    import imageio.v3 as iio

    out = render_sphere("surface")
    paths = save_image_outputs(tmp_path, out, "sphere")
    assert set(paths) == {"rgb", "normals", "mask", "depth"}
    normals_png = iio.imread(paths["normals"])
    expected = (normals_to_rgb(out.normals, out.mask) * 255).round().to(torch.uint8).numpy()
    assert np.array_equal(normals_png, expected)
    decoded = normals_png[out.mask.numpy()].astype(np.float64) / 255.0 * 2.0 - 1.0
    decoded /= np.linalg.norm(decoded, axis=-1, keepdims=True)
    cosine = (decoded * out.normals[out.mask].double().numpy()).sum(-1)
    assert cosine.min() > math.cos(math.radians(1.0))
    torch.testing.assert_close(torch.from_numpy(np.load(paths["depth"])), out.depth.float())
    assert np.array_equal(iio.imread(paths["mask"]) > 0, out.mask.numpy())
