"""Sensing models: measurement/process noise, drops, multi-rate reports, delays.

One module per concept: :mod:`.noise` (none, Gaussian, bounded uniform), :mod:`.drops`
(Bernoulli and Gilbert-Elliott arrivals), :mod:`.multirate` (asynchronous multi-rate
sensors), :mod:`.delays` (delay languages).
"""

from netsense.sensing.noise import GaussianNoise, NoiseModel, NoNoise, UniformNoise

__all__ = ["GaussianNoise", "NoNoise", "NoiseModel", "UniformNoise"]
