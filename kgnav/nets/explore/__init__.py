"""The learned global exploration policy (``ppo`` / ``ppo-semantic``): the paper's PPO policy.

* :mod:`~kgnav.nets.explore.net` — the network (5 conv layers, ReLU, max pooling, as Active Neural
  SLAM / SemExp) and its input: a multi-channel crop of the episode map;
* :mod:`~kgnav.nets.explore.mapenv` — the map-level environment it is trained in: between two
  decisions the agent follows the planner's path on the ground-truth map and the map is revealed
  by 2-D ray casting (no rendering);
* :mod:`~kgnav.nets.explore.train` — seeded, resumable PPO on the ``train`` houses;
* :mod:`~kgnav.nets.explore.weights` — the ``.npz`` weight file and its validation;
* :mod:`~kgnav.nets.explore.policy` — the registered global policies (``ppo``, ``ppo-semantic``,
  ``random-goal``);
* :mod:`~kgnav.nets.explore.bench` — explored area per policy on the map-level environment.

Nothing is imported here: ``make_policy("ppo")`` imports what it needs.
"""
