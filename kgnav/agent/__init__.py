"""The ObjectNav agent: the paper's per-step cycle (``loop.py``) and its swappable parts.

Knowledge extraction: :mod:`~kgnav.agent.segmenter`, :mod:`~kgnav.agent.features`,
:mod:`~kgnav.agent.state_creator`; knowledge modelling: :mod:`~kgnav.agent.mapping`,
:mod:`~kgnav.agent.memory`; reasoning: :mod:`~kgnav.agent.policy`,
:mod:`~kgnav.agent.planner`. :mod:`~kgnav.agent.oracle` is the ground-truth upper bound.
"""
