"""The agent's learned parts, each a network with shipped offline weights and a seeded training
command: the state encoder (:mod:`~kgnav.nets.encoder`), the RGB-D segmenter
(:mod:`~kgnav.nets.segnet`) and the exploration policy (:mod:`~kgnav.nets.explore`); what they
share: the ``.npz`` weight files (:mod:`~kgnav.nets.weights`) and the resumable training loop
(:mod:`~kgnav.nets.training`). Nothing is imported here: the agent imports a network (and torch)
only when asked for it by name."""
