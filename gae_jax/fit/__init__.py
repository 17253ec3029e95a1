"""Fitting the original avatar to multi-view video (GaussianAvatars-style): config, the jitted
step, densification, and the loop `fit`."""
