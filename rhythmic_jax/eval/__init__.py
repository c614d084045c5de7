"""Judging a map: ground truth and its files, metrics, the evaluation report
beside brute force, outlier rejection, nearest-neighbour baselines, SeqSLAM,
and the paper's figures."""
