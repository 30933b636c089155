"""How good a run is: the metrics (:mod:`.metrics`), the scoring of run folders
(:mod:`.evaluate`), and how hard a dataset's motion is: target and camera motion statistics
(:mod:`.motion_stats`) and the perfect-tracker oracle (:mod:`.oracle`)."""
