"""The ObjectNav agent: the paper's per-step cycle (``loop.py``) and its swappable parts.

Knowledge extraction: :mod:`~kgnav.agent.segmentation` (with the ground-truth
:mod:`~kgnav.agent.noise_segmenters`), :mod:`~kgnav.agent.features`,
:mod:`~kgnav.agent.state_creator`; knowledge modelling: :mod:`~kgnav.agent.mapping`,
:mod:`~kgnav.agent.memory`, :mod:`~kgnav.agent.relocation` (the in-loop, verified relocation);
reasoning: :mod:`~kgnav.agent.goals`, :mod:`~kgnav.agent.policy`, :mod:`~kgnav.agent.planner`.
:mod:`~kgnav.agent.oracle` is the ground-truth upper bound. The learned parts (encoder,
segmenter, exploration policy) are in :mod:`kgnav.nets`.
"""
