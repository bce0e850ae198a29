"""Models from the design documents, declared once each (see :mod:`.base`)."""

from ..context import Context
from .altitude import altitude_model
from .base import LinearModel, MeasurementModel, discretize, observability_rank

__all__ = ["altitude_model", "Context", "LinearModel", "MeasurementModel", "discretize", "observability_rank"]
