"""What every layer may use and that knows nothing of hands: atomic file writes and JSON
(:mod:`.io`), typed configs with overrides (:mod:`.config`), CPU threads (:mod:`.threads`), the
worker pool (:mod:`.pool`) and device settings (:mod:`.device`)."""
