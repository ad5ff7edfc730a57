"""The learned RGB-D segmenter (``learned`` / ``kgnav-segnet``): network, data, training, weights,
the agent-facing segmenter and its benchmark.

* :mod:`~kgnav.nets.segnet.net` — the RedNet-style encoder–decoder and its input preprocessing;
* :mod:`~kgnav.nets.segnet.data` — labelled views of the houses (class-balanced) and augmentation;
* :mod:`~kgnav.nets.segnet.train` — seeded, resumable supervised training;
* :mod:`~kgnav.nets.segnet.weights` — the ``.npz`` weight file and its validation;
* :mod:`~kgnav.nets.segnet.segmenter` — :class:`LearnedSegmenter`, :class:`ClassMapSegmenter`;
* :mod:`~kgnav.nets.segnet.bench` — scoring segmenters against ground truth.

Nothing is imported here: ``make_segmenter("learned")`` imports what it needs.
"""
