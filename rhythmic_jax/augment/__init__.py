"""Augmentation: the paper's seven kornia operations (seeded, replayable) and the
on-the-fly stream that trains a map on freshly augmented frames every epoch."""
