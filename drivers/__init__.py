"""Drivers: every protocol or file format turned into :class:`groundstation.core.measurement.Measurement`.

Units, frames and time bases are converted here, once, and nowhere else.
"""
