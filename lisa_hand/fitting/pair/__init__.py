"""Several hands fitted together: each hand's field evaluated at the other hands' surfaces
(contact allowed, overlap penalised), depth order from the masks, and what a fit of several
hands writes beside each hand's folder (``hands.json``, one mesh and one overlay of all)."""
