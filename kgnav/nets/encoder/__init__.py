"""The learned state-feature encoder (``kgnav-encoder``): network, weights, training, benchmark.

* :mod:`~kgnav.nets.encoder.net` — the small convolutional encoder and its input preprocessing;
* :mod:`~kgnav.nets.encoder.weights` — the ``.npz`` weight file with metadata, and its validation;
* :mod:`~kgnav.nets.encoder.extractor` — :class:`LearnedEncoder`, the registered feature extractor;
* :mod:`~kgnav.nets.encoder.views` — rendering views of the houses; when two views show one place;
* :mod:`~kgnav.nets.encoder.train` — self-supervised training (pose-contrastive or autoencoder);
* :mod:`~kgnav.nets.encoder.calibration` — the relocation benchmark and threshold calibration.
"""

from kgnav.nets.encoder.extractor import LearnedEncoder
from kgnav.nets.encoder.weights import (
           DEFAULT_WEIGHTS,
           EncoderWeights,
           EncoderWeightsError,
           load_weights,
)

__all__ = ["DEFAULT_WEIGHTS", "EncoderWeights", "EncoderWeightsError", "LearnedEncoder",
           "load_weights"]
