"""The LISA model: the field that combines bone frames, per-bone outputs and skinning weights
(:mod:`.lisa`), its losses (:mod:`.losses`, paper Eq. 13-20) and trained models as files
(:mod:`.trained`)."""

from .lisa import FieldOutput, FrameState, LisaModel, build_model

__all__ = ["FieldOutput", "FrameState", "LisaModel", "build_model"]
