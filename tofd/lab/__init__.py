"""Research tools on top of the algorithm: labelled datasets, synthetic scenes, training, evaluation, experiments."""
