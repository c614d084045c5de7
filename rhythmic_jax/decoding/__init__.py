"""Decoding decision values into places: the paper's hard decode (per-period
argmax and Chinese remainder, with its :class:`Decoded` result), soft and top-m
decodes, sequence decoding, and the dispatch between them by name."""
