"""Run a module with the GL state calls and also dispatches, draws, copies and clears holding the GIL."""
import ctypes
import runpy
import sys

from progressive import glext

MORE = {"glDispatchCompute", "glDispatchComputeIndirect", "glDrawArraysIndirect", "glCopyNamedBufferSubData",
        "glClearNamedBufferSubData", "glClearTexImage"}
def _entry(loader, name, *argtypes, restype=None, state=None):
    address = loader(name)
    if not address:
        raise RuntimeError(f"OpenGL entry point {name} not found")
    hold = bool(state) or name in glext.STATE_CALLS or name.startswith("glProgramUniform") or name in MORE
    return (ctypes.PYFUNCTYPE if hold else ctypes.CFUNCTYPE)(restype, *argtypes)(address)
glext._entry = _entry
sys.argv = sys.argv[1:]
runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
