"""How good a run is: the metrics (:mod:`.metrics`) and the scoring of run folders
(:mod:`.evaluate`)."""
