"""Attribute switch (paper 3.5): points per second streamed when the shown attribute
changes, for 1-, 2- and 4-component attributes.

PENDING: the attribute-streaming API is being built in the core. Until `Session` or
`Scene` has one of STREAM_METHODS, this section is skipped with a note; it does not
build the feature itself."""

from __future__ import annotations

from bench.report import Table
from progressive.scene import Scene
from progressive.session import Session

STREAM_METHODS = ("stream_attribute", "switch_attribute", "set_attribute")


def streaming_api() -> str | None:
    """`Class.method` of the first attribute-streaming entry point found, else None."""
    return next((f"{cls.__name__}.{name}" for cls in (Session, Scene) for name in STREAM_METHODS
                 if callable(getattr(cls, name, None))), None)


def run() -> Table:
    table = Table("attributes", "Attribute switch: points/s streamed (1-, 2-, 4-component attributes)",
                  "-", "-", ("components", "points/s"))
    api = streaming_api()
    if api is None:
        table.notes = [
            "**Skipped:** `progressive` has no attribute-streaming API yet (none of "
            + ", ".join(f"`{m}`" for m in STREAM_METHODS) + " on Session or Scene). It is being built in the "
            "core; this section measures it once it lands."]
    else:
        table.notes = [f"**Not measured:** `{api}` exists, but this bench predates it; wire it in bench/attributes.py."]
    table.raw = {"skipped": True, "api": api}
    return table
