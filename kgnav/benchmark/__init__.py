"""The benchmark: run agent variants over a split's episodes, score them, analyse failures."""
