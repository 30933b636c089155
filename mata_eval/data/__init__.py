"""Where sequences come from: dataset plugins (:mod:`.datasets`), the synthetic UAV suite
(:mod:`.synth`) and the occlusion augmentation (:mod:`.occlusion`)."""
