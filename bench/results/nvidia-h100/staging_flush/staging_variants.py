"""Probe: the staging ring as committed (VARIANT=flushed: a mapping that is not coherent,
each piece flushed, then a client-mapped buffer barrier) or as it was before 14e6b92
(VARIANT=coherent: mapped persistent and coherent, neither flush nor barrier). Imported
at start by sitecustomize.py beside it (PYTHONPATH=this folder), so a bench's child
processes take the same variant."""
import ctypes
import os

import numpy as np

VARIANT = os.environ.get("VARIANT", "flushed")

if VARIANT == "coherent":
    from progressive import glext
    from progressive.bindings import Binding
    from progressive.passes import distribute

    def mapped(self, size):
        name = glext._u(0)
        self.create_buffers(1, ctypes.byref(name))
        flags = glext.GL_MAP_WRITE_BIT | glext.GL_MAP_PERSISTENT_BIT | 0x0080     # GL_MAP_COHERENT_BIT
        self.named_buffer_storage(name.value, size, None, flags)
        address = self.map_named_buffer_range(name.value, 0, size, flags)
        if not address:
            raise RuntimeError("could not map")
        words = np.ctypeslib.as_array(ctypes.cast(address, ctypes.POINTER(ctypes.c_uint32)), shape=(size // 4,))
        return glext.MappedBuffer(int(name.value), size, words)

    def bind(self, slot, size):
        self.buffer.bind_to_storage_buffer(Binding.DISTRIBUTE, offset=slot * self.slot_bytes, size=size)

    glext.BufferStorage.mapped = mapped
    distribute.StagingRing.bind = bind
else:
    assert VARIANT == "flushed", VARIANT
