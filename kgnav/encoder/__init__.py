"""The learned state-feature encoder (``kgnav-encoder``): network, weights, training, benchmark.

* :mod:`~kgnav.encoder.net` — the small convolutional encoder and its input preprocessing;
* :mod:`~kgnav.encoder.weights` — the ``.npz`` weight file with metadata, and its validation;
* :mod:`~kgnav.encoder.extractor` — :class:`LearnedEncoder`, the registered feature extractor;
* :mod:`~kgnav.encoder.views` — rendering views of the houses; when two views show one place;
* :mod:`~kgnav.encoder.train` — self-supervised training (pose-contrastive or autoencoder);
* :mod:`~kgnav.encoder.relocation` — the relocation benchmark and threshold calibration.
"""

from kgnav.encoder.extractor import LearnedEncoder
from kgnav.encoder.weights import DEFAULT_WEIGHTS, EncoderWeights, EncoderWeightsError, load_weights

__all__ = ["DEFAULT_WEIGHTS", "EncoderWeights", "EncoderWeightsError", "LearnedEncoder",
           "load_weights"]
