"""Reading LAS/LAZ and the fast format into batches for the GPU."""

from progressive.loaders import lean_imports  # noqa: F401  (first: laspy imported lean before any loader imports it)
from progressive.loaders.describe import describe, format_text
from progressive.loaders.fastformat import positioned, write_fast, write_fast_stream
from progressive.loaders.pipeline import CloudLoader, open_cloud
from progressive.loaders.types import BATCH_POINTS

__all__ = ["BATCH_POINTS", "CloudLoader", "describe", "format_text", "open_cloud", "positioned", "write_fast", "write_fast_stream"]
