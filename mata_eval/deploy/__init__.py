"""Towards the board: exporting trackers (:mod:`.export`) and measuring block timing profiles on a
machine (:mod:`.profile`)."""
