"""Importers of real datasets into the package's layout (:mod:`lisa_hand.data.layout`):
InterHand2.6M (:mod:`.interhand`), FreiHAND (:mod:`.freihand`) and folders of scans
(:mod:`.scans`); the shared writer is :mod:`.common`, MANO parameters :mod:`.mano_params`.
See ``docs/datasets.md``."""
