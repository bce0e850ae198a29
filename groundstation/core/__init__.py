"""The core every layer shares: the measurement record, units, frames, the atmosphere, fan-out."""
