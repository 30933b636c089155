"""Running trackers on sequences: the experiment file (:mod:`.config`), the camera-clock
scheduler of the three blocks (:mod:`.scheduler`) and its timing profiles
(:mod:`.timing_profile`), the runner that drives sequences through worker processes
(:mod:`.runner`) and the run folders it writes (:mod:`.results`)."""
