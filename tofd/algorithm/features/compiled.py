"""The NFFT path's compiled loops (numba modules of this package), imported on first use.

numba and LLVM add about 40 MB of private memory (100 MB resident) to a process, so the NFFT path imports its
compiled modules only when it first computes: the feature workers load them, the service and viewer processes do not.
"""

import functools
import importlib
from types import ModuleType


@functools.cache
def compiled(name: str) -> ModuleType:
    """This package's compiled module `name` (e.g. "cg_kernels"), imported on the first call."""
    return importlib.import_module(f"{__package__}.{name}")
