"""Estimation: the design documents' models, their filters, the routing of measurements to
them, the asyncio estimation loop, and the one registry of models by name."""
