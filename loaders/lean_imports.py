"""laspy imported without `requests` and `pyproj`, before any module of the loaders
imports it.

laspy imports both at its own import: `requests` for its CopcReader over HTTP alone,
`pyproj` in its GeoTIFF module for a type annotation (every laspy function that uses
pyproj imports it where it runs). Together they cost 0.1-0.3 s of every command's start
on the H100 machine (the CLI imported in 0.63-0.83 s with them, 0.49-0.56 s without:
bench/results/nvidia-h100/startup_import/).
progressive reads URLs through loaders/http.py, never through laspy, and imports pyproj
where a coordinate system is asked for. laspy takes a module it cannot import as
missing, so while laspy is imported these are marked not importable; the marks are taken
back at once, so any later import of them works. Where laspy or one of them was imported
before, nothing changes. The one cost: in a process that imported progressive first,
laspy's own CopcReader refuses http(s) URLs (its message says `requests` is missing);
local files are unchanged.
"""

import sys

SKIPPED = ("requests", "pyproj")


def import_laspy() -> None:
    """laspy imported with the modules of SKIPPED not yet imported marked not importable meanwhile."""
    if "laspy" in sys.modules:
        return
    marked = [name for name in SKIPPED if name not in sys.modules]
    for name in marked:
        sys.modules[name] = None
    try:
        import laspy  # noqa: F401
    finally:
        for name in marked:
            if name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]


import_laspy()
