"""Hardware-in-the-loop ground station for small rotorcraft.

Core: the measurement record, sessions (recording, replay), the estimation
loop and models, diagnosis, and the ``groundstation`` command line.
"""

__version__ = "0.1.0"
