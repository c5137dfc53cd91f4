"""FreiHAND / InterHand2.6M scores on closed forms, and a predictor over an imported split."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lisa_hand.data.importers.freihand import FreiHandConfig, import_freihand
from lisa_hand.evaluation.real_formats import (
    Prediction,
    evaluate_split,
    f_score,
    freihand_scores,
    pa_mpvpe,
)
from lisa_hand.utils.io import read_json
from tests.data.importers.fixtures import freihand_fixture
from tests.skeleton.synthetic_mano import write_synthetic_mano


def imported_freihand(tmp_path, num: int):
    """A FreiHAND fixture of ``num`` samples (with a synthetic MANO) imported into
    ``tmp_path / "DATA"`` with its vertices -> that folder."""
    mano_dir = tmp_path / "mano"
    mano_dir.mkdir()
    write_synthetic_mano(mano_dir / "MANO_RIGHT.pkl", "right", seed=2)
    freihand_fixture(tmp_path / "FreiHAND", num=num, mano_dir=mano_dir)
    data = tmp_path / "DATA"
    import_freihand(FreiHandConfig(root=str(tmp_path / "FreiHAND"), vertices=True,
                                   mano=str(mano_dir), skinning_points=0), data, progress=False)
    return data


def test_f_score_closed_form():
    true = np.zeros((4, 3))
    true[:, 0] = [0.0, 0.01, 0.02, 0.03]
    pred = true.copy()
    pred[3, 1] = 0.008  # one predicted point 8 mm off (its nearest true point: itself, 8 mm)
    f5, precision, recall = f_score(pred, true, 0.005)
    # The last true point's nearest prediction is 8 mm away (pred[3]; pred[2] is 10 mm), and
    # pred[3]'s nearest true point too (true[3], 8 mm): P = R = 3/4.
    assert precision == pytest.approx(0.75) and recall == pytest.approx(0.75)
    assert f5 == pytest.approx(0.75)
    assert f_score(pred, true, 0.015)[0] == pytest.approx(1.0)
    assert f_score(true + [1.0, 0, 0], true, 0.005)[0] == 0.0
    with pytest.raises(ValueError, match="threshold_m"):
        f_score(pred, true, 0.0)


def test_procrustes_scores_ignore_similarities():
    rng = np.random.default_rng(0)
    vertices = 0.05 * rng.standard_normal((100, 3))
    keypoints = vertices[:21]
    rotation = Rotation.from_rotvec([0.3, -1.0, 0.5]).as_matrix()
    moved_v = 1.3 * vertices @ rotation.T + [0.1, 0.2, 0.3]
    moved_k = moved_v[:21]
    scores = freihand_scores(moved_k, keypoints, moved_v, vertices)
    assert scores["pa_mpjpe_mm"] < 1e-9 and scores["pa_mpvpe_mm"] < 1e-9
    assert scores["f5"] == 1.0 and scores["f15"] == 1.0
    assert scores["mpjpe_mm"] > 10  # rotation and scale are errors without alignment
    # Another topology (no correspondence): aligned by the keypoints, same result.
    other = freihand_scores(moved_k, keypoints, np.concatenate([moved_v, moved_v[:1]]), vertices)
    assert "pa_mpvpe_mm" not in other and other["f5"] == 1.0
    noisy = vertices + 0.002 * rng.standard_normal(vertices.shape)
    assert 1.5 < pa_mpvpe(noisy, vertices) < 4.0


def test_evaluate_an_imported_freihand_split(tmp_path):
    data = imported_freihand(tmp_path, num=3)
    from lisa_hand.data.layout import read_npz

    def perfect(paths):
        params = read_json(paths.params)
        return Prediction(keypoints=np.asarray(params["keypoints"]) + [0.01, 0.0, 0.0],
                          vertices=read_npz(paths.root / "mano_mesh.npz")["vertices"])

    scores = evaluate_split(data, "test", perfect, out=tmp_path / "scores.json")
    assert scores.dataset == "FreiHAND" and len(scores.frames) == 2
    means = scores.means
    assert means["mpjpe_mm"] < 1e-9 and means["pa_mpvpe_mm"] < 1e-9 and means["f5"] == 1.0
    assert read_json(tmp_path / "scores.json")["num_frames"] == 2

    def broken(paths):
        raise ValueError("no hand found")

    failed = evaluate_split(data, "test", broken)
    assert len(failed.failed) == 2 and "no hand found" in failed.failed[0]


def test_photo_fit_predictor_on_an_imported_freihand_frame(tmp_path):
    """The fit-photo predictor with the frame's K and its 2D keypoints (a tiny model, a fast
    fit): its 3D keypoints, moved to the dataset's frame, project onto the fitted 2D ones."""
    import torch

    from lisa_hand.data.datasets import read_frame_table
    from lisa_hand.evaluation.real_formats import photo_fit_predictor
    from lisa_hand.geometry.cameras import load_cameras
    from lisa_hand.model.trained import export_trained
    from lisa_hand.utils.threads import cpu_threads
    from tests.fitting.image_scene import tiny_model
    from tests.fitting.photo.test_fit_photo import fast_config

    data = imported_freihand(tmp_path, num=1)
    model_path, _ = export_trained(tiny_model(), tmp_path / "model.pt")
    predict = photo_fit_predictor(tmp_path / "fits", model_path=model_path, device="cpu",
                                  config=fast_config())
    predictions = []

    def recording(paths):
        predictions.append(predict(paths))
        return predictions[-1]

    with cpu_threads(1):
        scores = evaluate_split(data, "test", recording)
    assert len(scores.frames) == 1, scores.failed
    row = scores.frames[0]["scores"]
    assert np.isfinite(row["mpjpe_mm"]) and np.isfinite(row["pa_mpjpe_mm"])
    assert 0.0 <= row["f5"] <= row["f15"] <= 1.0 and "pa_mpvpe_mm" not in row  # LISA's mesh
    frame = read_frame_table(data, "test").frames[0]
    camera = load_cameras(frame.cameras, dtype=torch.float64)[0]
    fitted = read_json(tmp_path / "fits" / "s000_f000" / "keypoints.json")
    pixels, _ = camera.project(torch.from_numpy(predictions[0].keypoints))
    assert np.abs(pixels.numpy() - np.asarray(fitted["keypoints_2d_fitted"])).max() < 0.5


def test_lisa_eval_real_scores_an_imported_split(tmp_path, monkeypatch, capsys):
    """``lisa eval DATA --real``: the predictor of each frame (here a stand-in for the photo
    fit, 2 mm off along x), the scores written after every frame, ``--frames`` honoured."""
    import lisa_hand.evaluation.real_formats as real_formats
    from lisa_hand.cli.main import main
    from lisa_hand.data.layout import read_npz

    data = imported_freihand(tmp_path, num=3)
    seen = {}

    def stand_in(work_dir, *, keypoints="given", model_path=None, device="auto"):
        seen.update(work_dir=work_dir, keypoints=keypoints)

        def predict(paths):
            params = read_json(paths.params)
            return Prediction(keypoints=np.asarray(params["keypoints"]) + [0.002, 0.0, 0.0],
                              vertices=read_npz(paths.root / "mano_mesh.npz")["vertices"])

        return predict

    monkeypatch.setattr(real_formats, "photo_fit_predictor", stand_in)
    out = tmp_path / "eval"
    with pytest.raises(SystemExit) as exit_:
        main(["eval", str(data), "--real", "--out", str(out), "--frames", "1"])
    assert exit_.value.code in (0, None)
    results = read_json(out / "results.json")
    assert results["dataset"] == "FreiHAND" and results["num_frames"] == 1
    # A shift moves no root-aligned or Procrustes-aligned keypoint.
    assert results["means"]["mpjpe_mm"] == pytest.approx(0.0, abs=1e-6)
    assert seen["keypoints"] == "given" and seen["work_dir"] == out / "fits"
    printed = capsys.readouterr().out
    assert "[1/1]" in printed and "1 frames scored, 0 failed" in printed
    with pytest.raises(SystemExit) as exit_:
        main(["eval", "--real", "--out", str(out)])
    assert exit_.value.code == 2
    assert "--real needs DATA" in capsys.readouterr().err


def test_interacting_frames_scored_per_hand_and_by_mrrpe(tmp_path):
    """The imported InterHand2.6M fixture's interacting frame gives a pair of frames (right,
    left): a predictor off by 10 mm along x for right hands and 4 mm along y for left ones
    scores MRRPE sqrt(10^2 + 4^2) mm on that pair alone; a predictor with ``pair`` is given the
    two hands at once, once."""
    from lisa_hand.data.frame_table import read_frame_table
    from lisa_hand.data.importers.interhand import InterHandConfig, import_interhand
    from lisa_hand.evaluation.real_formats import interacting_pairs
    from tests.data.importers.fixtures import interhand_fixture

    interhand_fixture(tmp_path / "IH")
    data = tmp_path / "DATA"
    import_interhand(InterHandConfig(root=str(tmp_path / "IH")), data, progress=False)
    frames = read_frame_table(data, "train").frames
    pairs = interacting_pairs(frames)
    assert len(pairs) == 2 and len(set(pairs.values())) == 1
    right, left = next(iter(pairs.values()))
    assert read_json(frames[right].params)["side"] == "right"
    assert read_json(frames[left].params)["side"] == "left"
    offsets = {"right": np.array([0.01, 0.0, 0.0]), "left": np.array([0.0, 0.004, 0.0])}

    def shifted(paths):
        params = read_json(paths.params)
        return Prediction(keypoints=np.asarray(params["keypoints"]) + offsets[params["side"]])

    scores = evaluate_split(data, "train", shifted)
    assert len(scores.frames) == len(frames) and len(scores.pairs) == 1
    assert scores.pairs[0]["mrrpe_mm"] == pytest.approx(np.hypot(10.0, 4.0), rel=1e-9)
    assert scores.means["mrrpe_mm"] == pytest.approx(np.hypot(10.0, 4.0), rel=1e-9)
    assert scores.means["mpjpe_mm"] < 1e-9  # root-aligned: a shift costs nothing

    class Pairing:
        def __init__(self):
            self.calls = []

        def __call__(self, paths):
            return shifted(paths)

        def pair(self, right_paths, left_paths):
            self.calls.append((right_paths.root, left_paths.root))
            return shifted(right_paths), shifted(left_paths)

    pairing = Pairing()
    again = evaluate_split(data, "train", pairing)
    assert pairing.calls == [(frames[right].root, frames[left].root)]
    assert again.pairs == scores.pairs
