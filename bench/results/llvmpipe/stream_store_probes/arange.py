"""np.arange against np.zeros (one node's slice written) for a 4 GiB store's file-order map
(255 M uint32 indices), three times each in one process."""
import time

import numpy as np

N = 255_000_000
for _ in range(3):
    t = time.perf_counter()
    a = np.arange(N, dtype=np.uint32)
    t1 = time.perf_counter()
    del a
    b = np.zeros(N, np.uint32)
    b[:40_000] = 1
    t2 = time.perf_counter()
    del b
    print(f"arange {t1 - t:.3f} s, zeros and a node's slice {t2 - t1:.4f} s", flush=True)
