"""Run a module with every GL entry point releasing the GIL (the tree before STATE_CALLS)."""
import ctypes
import runpy
import sys

from progressive import glext


def _entry(loader, name, *argtypes, restype=None, state=None):
    address = loader(name)
    if not address:
        raise RuntimeError(f"OpenGL entry point {name} not found")
    return ctypes.CFUNCTYPE(restype, *argtypes)(address)
glext._entry = _entry
sys.argv = sys.argv[1:]
runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
