"""``python -m lisa_hand.data.merge``: one dataset from several, splits kept, subjects linked."""

import json

import pytest

from lisa_hand.data.layout import list_frames, read_split
from lisa_hand.data.merge import main, merge_datasets


def _dataset(root, split, hand_model):
    """A dataset folder as ``lisa synth`` lays it out (one empty frame folder a subject)."""
    root.mkdir()
    (root / "dataset.json").write_text(json.dumps({"format": "lisa-synth",
                                                   "config": {"hand_model": hand_model}}))
    (root / "split.json").write_text(json.dumps(split))
    for subject in sum(split.values(), []):
        (root / subject / "f000").mkdir(parents=True)
        (root / subject / "subject.json").write_text(json.dumps({"id": subject}))
    return root


@pytest.fixture
def two(tmp_path):
    a = _dataset(tmp_path / "v2", {"train": ["s000", "s002"], "val": ["s003"], "test": ["s001"]},
                 "v2")
    b = _dataset(tmp_path / "v1", {"train": ["s000"], "val": [], "test": ["s001", "s004"]}, "v1")
    return a, b


def test_merge_keeps_each_split_and_links_the_subjects(two, tmp_path):
    a, b = two
    out = tmp_path / "mix"
    split = merge_datasets(out, [(a, ""), (b, "v1")])
    assert split == {"train": ["s000", "s002", "v1s000"], "val": ["s003"],
                     "test": ["s001", "v1s001", "v1s004"]}
    assert read_split(out) == split
    assert (out / "v1s004").is_symlink() and (out / "v1s004").resolve() == (b / "s004").resolve()
    # the training reader finds every frame through the links
    assert len(list_frames(out, split["train"])) == 3
    dataset = json.loads((out / "dataset.json").read_text())
    assert dataset["config"] == {"hand_model": "v2"}  # the first source's
    assert [(m["prefix"], m["train"], m["test"]) for m in dataset["merged_from"]] == [
        ("", 2, 1), ("v1", 1, 2)]
    # merging again replaces the earlier merge's links
    again = merge_datasets(out, [(b, "v1")])
    assert again["train"] == ["v1s000"] and not (out / "s002").exists()


def test_merge_refuses_clashes_and_foreign_folders(two, tmp_path, capsys):
    a, b = two
    with pytest.raises(ValueError, match="'s000' is also in .*give one source a prefix"):
        merge_datasets(tmp_path / "mix", [(a, ""), (b, "")])
    assert not (tmp_path / "mix").exists()  # nothing written
    with pytest.raises(ValueError, match="not a merged dataset"):
        merge_datasets(a, [(b, "v1")])  # a real dataset folder is not overwritten
    with pytest.raises(ValueError, match="cannot be one of the sources"):
        merge_datasets(b, [(b, "x")])
    with pytest.raises(ValueError, match="prefix"):
        merge_datasets(tmp_path / "mix", [(a, "a/b")])
    with pytest.raises(SystemExit) as exit_info:
        main([str(tmp_path / "mix"), str(a), str(b)])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.startswith("error: ")
    main([str(tmp_path / "mix"), str(a), f"{b}=v1"])
    assert "7 subjects (3 train, 1 val, 3 test)" in capsys.readouterr().out
