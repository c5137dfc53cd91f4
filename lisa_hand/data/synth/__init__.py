"""The dataset generator behind ``lisa synth`` (:func:`synthesize`, :mod:`.dataset`): subjects of
the open hand model (:mod:`.scene`: the seeded random choices), each frame written by
:mod:`.frame` (mesh, scan, SDF samples, images, masks, depth, keypoints), settings and summary in
:mod:`.config`, a contact sheet in :mod:`.preview`, hand model v1 beside v2 in :mod:`.compare`."""

from .dataset import (
    GENERATOR_VERSION,
    FrameSetup,
    SubjectRecord,
    SynthConfig,
    SynthSummary,
    dataset_rig,
    frame_setup,
    make_subject,
    parse_resolution,
    split_subjects,
    synthesize,
    write_preview,
)

__all__ = ["GENERATOR_VERSION", "SynthConfig", "SynthSummary", "SubjectRecord", "FrameSetup",
           "parse_resolution", "split_subjects", "make_subject", "dataset_rig", "frame_setup",
           "synthesize", "write_preview"]
