"""Layer 2 — sensing models: measurement/process noise, drops, multi-rate reports, delays.

One module per concept: :mod:`.noise` (none, Gaussian, bounded uniform), :mod:`.drops`
(Bernoulli and Gilbert-Elliott arrivals), :mod:`.multirate` (asynchronous multi-rate
sensors), :mod:`.delays` (delay languages), :mod:`.arrivals` (the arrival-model base).

May import: :mod:`netsense.kernels` (compiled draws of many members' noise at once).
"""

from netsense.sensing.noise import GaussianNoise, NoiseModel, NoNoise, UniformNoise

__all__ = ["GaussianNoise", "NoNoise", "NoiseModel", "UniformNoise"]
