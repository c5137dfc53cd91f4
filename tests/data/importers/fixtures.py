"""Small datasets written in exactly the formats of InterHand2.6M and FreiHAND (for tests).

Hands come from the open model's MANO-like template (``lisa_hand/assets/template.npz``, random
poses and shapes) or, for MANO-annotated frames, from a synthetic MANO file in the official
layout (:mod:`tests.skeleton.synthetic_mano`); cameras look at the hand from about a metre.
Every number is written in the dataset's own units and order, and the dataset's own projection
(``cam2pixel`` of InterHand2.6M, ``projectPoints`` of FreiHAND) is computed here, independently
of the package, for the tests to compare against.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from lisa_hand.handmodel.poses import sample_pose
from lisa_hand.handmodel.template import load_template
from lisa_hand.skeleton import ManoLayer, mirror_points

F64 = torch.float64
# InterHand2.6M's joint order for one hand: index of each of its 21 joints in OpenPose order.
OPENPOSE_OF_INTERHAND = [4, 3, 2, 1, 8, 7, 6, 5, 12, 11, 10, 9, 16, 15, 14, 13, 20, 19, 18, 17, 0]


def look_at_mm(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """camrot (world -> camera) of a camera at ``eye`` looking at ``target`` (y down)."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, -1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def cam2pixel_mm(world_mm: np.ndarray, campos: np.ndarray, camrot: np.ndarray,
                 focal: np.ndarray, princpt: np.ndarray) -> np.ndarray:
    """InterHand2.6M's own projection (world2cam then cam2pixel), [N, 2] px."""
    cam = (camrot @ (world_mm - campos).T).T
    return cam[:, :2] / cam[:, 2:] * focal + princpt


class TemplateHands:
    """Right-hand keypoints [21, 3] metres of the template at random poses."""

    def __init__(self, seed: int = 0) -> None:
        self.template = load_template().to(dtype=F64)
        self.generator = torch.Generator().manual_seed(seed)

    def keypoints(self, betas: torch.Tensor, num: int, translation: np.ndarray) -> np.ndarray:
        pose = sample_pose(self.generator, num, global_orient=True).to(F64)
        out = self.template(pose, betas.expand(num, -1),
                            torch.as_tensor(translation, dtype=F64).expand(num, 3))
        return out.keypoints.numpy()


def interhand_fixture(root: Path, *, mano_dir: Path | None = None, masks: bool = False,
                      seed: int = 0) -> dict:
    """Write an InterHand2.6M-style ``train`` split under ``root`` and return what it holds.

    Capture0 (subject 0): frames 0-3 right hand, 4-5 left hand, 6 interacting, 7 without a 3D
    annotation, 8 with an invalid right-hand joint, 9 with one camera's image missing.
    With ``masks``: ``root/masks`` (mirroring images/train, .png) with the hands' keypoint
    boxes. With ``mano_dir`` (synthetic MANO_RIGHT/LEFT.pkl): Capture1 (subject 1), frames 0-3
    right and left hands from the MANO layer with MANO_NeuralAnnot entries (one shape per hand).
    -> {"world_mm": {(capture, frame): [42, 3]}, "cameras": {capture: {cam: params}},
    "images": {(capture, frame, cam): path}, "mano": {(capture, frame, side): entry}}
    """
    rng = np.random.default_rng(seed)
    hands = TemplateHands(seed)
    betas = {"right": 0.7 * torch.randn(1, hands.template.num_betas, generator=hands.generator,
                                        dtype=F64)}
    betas["left"] = 0.7 * torch.randn(1, hands.template.num_betas, generator=hands.generator,
                                      dtype=F64)
    cams = ["400002", "400004", "400006"]
    width, height = 334, 512
    centre_mm = np.array([30.0, -50.0, 900.0])
    captures = [0] + ([1] if mano_dir is not None else [])
    camera_json, images, annotations, joints_json, mano_json = {}, [], [], {}, {}
    info = {"world_mm": {}, "cameras": {}, "images": {}, "mano": {}}
    for capture in captures:
        params = {"campos": {}, "camrot": {}, "focal": {}, "princpt": {}}
        for k, cam in enumerate(cams):
            angle = 2 * np.pi * k / len(cams) + 0.3
            eye = centre_mm + np.array([900 * np.sin(angle), 150.0 * k - 150, -900 * np.cos(
                angle)])
            params["campos"][cam] = eye.tolist()
            params["camrot"][cam] = look_at_mm(eye, centre_mm).tolist()
            params["focal"][cam] = [1200.0 + 10 * k, 1200.0 - 5 * k]
            params["princpt"][cam] = [width / 2 + 3.0 * k, height / 2 - 2.0 * k]
        camera_json[str(capture)] = params
        info["cameras"][capture] = params
        joints_json[str(capture)] = {}
        if capture == 0:
            right = hands.keypoints(betas["right"], 10, centre_mm * 1e-3)
            left = mirror_points(torch.from_numpy(hands.keypoints(
                betas["left"], 10, [0.0, 0.0, 0.0]))).numpy() + centre_mm * 1e-3 + [0.08, 0, 0]
            types = ["right"] * 4 + ["left"] * 2 + ["interacting", "right", "right", "right"]
        else:
            right, left, types = _mano_hands(mano_dir, centre_mm, rng, info, mano_json)
        for frame, hand_type in enumerate(types):
            world = np.zeros((42, 3))
            world[:21] = right[frame][OPENPOSE_OF_INTERHAND] * 1e3
            world[21:] = left[frame][OPENPOSE_OF_INTERHAND] * 1e3
            valid = np.zeros(42)
            if hand_type in ("right", "interacting"):
                valid[:21] = 1
            if hand_type in ("left", "interacting"):
                valid[21:] = 1
            if capture == 0 and frame == 8:
                valid[5] = 0  # right index distal joint
            info["world_mm"][(capture, frame)] = world
            if not (capture == 0 and frame == 7):
                joints_json[str(capture)][str(frame)] = {
                    "world_coord": world.tolist(), "joint_valid": valid.tolist(),
                    "hand_type": hand_type, "hand_type_valid": 1}
            for cam in cams:
                image_id = len(images)
                seq = "0000_neutral_relaxed" if frame < 5 else "ROM03_RT_No_Occlusion"
                name = f"Capture{capture}/{seq}/cam{cam}/image{frame:04d}.jpg"
                images.append({"id": image_id, "file_name": name, "width": width,
                               "height": height, "capture": capture, "subject": capture,
                               "seq_name": seq, "camera": cam, "frame_idx": frame})
                annotations.append({"id": image_id, "image_id": image_id,
                                    "bbox": [0, 0, 10, 10], "joint_valid": [[v] for v in valid],
                                    "hand_type": hand_type, "hand_type_valid": 1})
                path = root / "images" / "train" / name
                if capture == 0 and frame == 9 and cam == "400004":
                    continue  # the missing image
                _write_jpeg(path, width, height, rng)
                info["images"][(capture, frame, cam)] = path
                if masks:
                    pixels = cam2pixel_mm(world[valid > 0], np.asarray(params["campos"][cam]),
                                          np.asarray(params["camrot"][cam]),
                                          np.asarray(params["focal"][cam]),
                                          np.asarray(params["princpt"][cam]))
                    _write_box_mask(root / "masks" / Path(name).with_suffix(".png"), width,
                                    height, pixels)
    folder = root / "annotations" / "train"
    folder.mkdir(parents=True, exist_ok=True)
    for name, content in (("data", {"images": images, "annotations": annotations}),
                          ("camera", camera_json), ("joint_3d", joints_json)):
        (folder / f"InterHand2.6M_train_{name}.json").write_text(json.dumps(content))
    if mano_json:
        (folder / "InterHand2.6M_train_MANO_NeuralAnnot.json").write_text(json.dumps(mano_json))
    return info


def _mano_hands(mano_dir: Path, centre_mm: np.ndarray, rng: np.random.Generator, info: dict,
                mano_json: dict):
    """Capture 1: four interacting frames posed by the synthetic MANO with NeuralAnnot entries."""
    result = {}
    mano_json["1"] = {}
    for side in ("right", "left"):
        # InterHand2.6M's code poses left hands with MANO_LEFT.pkl's shapedirs quirk fixed.
        layer = ManoLayer(mano_dir / f"MANO_{side.upper()}.pkl", side, dtype=F64,
                          fix_left_shapedirs=side == "left")
        shape = rng.standard_normal(10)
        poses = 0.4 * rng.standard_normal((4, 48))
        trans = centre_mm * 1e-3 + 0.02 * rng.standard_normal((4, 3))
        out = layer(hand_pose=torch.from_numpy(poses[:, 3:]),
                    global_orient=torch.from_numpy(poses[:, :3]),
                    betas=torch.from_numpy(np.tile(shape, (4, 1))), transl=torch.from_numpy(trans))
        result[side] = out.keypoints.numpy()
        for frame in range(4):
            entry = {"pose": poses[frame].tolist(), "shape": shape.tolist(),
                     "trans": trans[frame].tolist()}
            mano_json["1"].setdefault(str(frame), {})[side] = entry
            info["mano"][(1, frame, side)] = entry
    return result["right"], result["left"], ["interacting"] * 4


def _write_box_mask(path: Path, width: int, height: int, pixels: np.ndarray) -> None:
    import imageio.v3 as iio

    low = np.clip(np.floor(pixels.min(0)).astype(int) - 5, 0, [width, height])
    high = np.clip(np.ceil(pixels.max(0)).astype(int) + 5, 0, [width, height])
    mask = np.zeros((height, width), np.uint8)
    mask[low[1]:high[1], low[0]:high[0]] = 255
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, mask, extension=".png")


def _write_jpeg(path: Path, width: int, height: int, rng: np.random.Generator) -> None:
    import imageio.v3 as iio

    path.parent.mkdir(parents=True, exist_ok=True)
    pixels = rng.integers(0, 255, size=(height, width, 3), dtype=np.uint8)
    iio.imwrite(path, pixels, extension=".jpg")


def project_points_freihand(xyz: np.ndarray, K: np.ndarray) -> np.ndarray:
    """FreiHAND's own ``projectPoints``: uv = (K xyz^T)^T, divided by z."""
    uv = (K @ xyz.T).T
    return uv[:, :2] / uv[:, -1:]


def freihand_fixture(root: Path, num: int = 4, *, mano_dir: Path | None = None,
                     seed: int = 0) -> dict:
    """Write a FreiHAND-style ``training`` set of ``num`` samples (4 image versions each, masks)
    under ``root``: sample 1 has NaN keypoints, version 2 of sample 2 has no image. With
    ``mano_dir`` the hands come from its MANO_RIGHT.pkl and ``training_mano.json`` is written
    (pose without the mean hand, shape, uv root, scale), with ``training_verts.json``.
    -> {"xyz": [num, 21, 3], "K": [num, 3, 3], "mano": [num, 61] or None, "verts"}
    """
    import imageio.v3 as iio

    rng = np.random.default_rng(seed)
    hands = TemplateHands(seed)
    xyz, verts, mano, full_poses = [], [], [], []
    for index in range(num):
        root_m = np.array([0.01 * index, -0.02, 0.6 + 0.05 * index])
        if mano_dir is None:
            betas = 0.5 * torch.randn(1, hands.template.num_betas, generator=hands.generator,
                                      dtype=F64)
            xyz.append(hands.keypoints(betas, 1, root_m)[0])
            continue
        layer = ManoLayer(mano_dir / "MANO_RIGHT.pkl", "right", dtype=F64)
        pose = 0.4 * rng.standard_normal(48)
        shape = rng.standard_normal(10)
        rest = layer(betas=torch.from_numpy(shape[None])).rest_joints[0].numpy()
        out = layer(hand_pose=torch.from_numpy(pose[None, 3:]),
                    global_orient=torch.from_numpy(pose[None, :3]),
                    betas=torch.from_numpy(shape[None]),
                    transl=torch.from_numpy((root_m - rest[0])[None]))
        xyz.append(out.keypoints[0].numpy())
        verts.append(out.vertices[0].numpy())
        # FreiHAND's HandModel(use_mean_pose=True) adds the mean hand to the stored pose.
        full_poses.append(np.concatenate([pose[:3], pose[3:] + layer.hand_mean.numpy()]))
        mano.append(np.concatenate([pose, shape, [112.0, 112.0], [1.0]]))
    K = np.stack([np.array([[480.0 + i, 0, 112.0 + i], [0, 481.0, 111.0], [0, 0, 1]])
                  for i in range(num)])
    annotated = [x.tolist() for x in xyz]
    if num > 1:
        annotated[1] = [[float("nan")] * 3] * 21
    root.mkdir(parents=True, exist_ok=True)
    (root / "training_K.json").write_text(json.dumps(K.tolist()))
    (root / "training_xyz.json").write_text(json.dumps(annotated))
    if mano:
        (root / "training_mano.json").write_text(json.dumps([[m.tolist()] for m in mano]))
        (root / "training_verts.json").write_text(json.dumps([v.tolist() for v in verts]))
    for version in range(4):
        for index in range(num):
            if index == 2 and version == 2:
                continue
            path = root / "training" / "rgb" / f"{index + version * num:08d}.jpg"
            path.parent.mkdir(parents=True, exist_ok=True)
            iio.imwrite(path, rng.integers(0, 255, (224, 224, 3), dtype=np.uint8),
                        extension=".jpg")
    for index in range(num):
        path = root / "training" / "mask" / f"{index:08d}.jpg"
        path.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(path, np.full((224, 224), 255, np.uint8), extension=".jpg")
    return {"xyz": np.stack(xyz), "K": K, "mano": np.stack(mano) if mano else None,
            "full_pose": np.stack(full_poses) if full_poses else None,
            "verts": np.stack(verts) if verts else None}
