"""The C library's ``pow`` and ``powf``, callable from compiled code.

Gymnasium's tasks square NumPy scalars with ``**``, which NumPy computes with the C library's pow (powf for a
float32), not by a multiplication; for about one value in a thousand the two differ in the last bit. Compiled code
cannot ask LLVM for pow(x, 2) either (it turns it into x·x), so the tasks call these instead where Gymnasium's
``**`` meets a NumPy scalar: their episodes then stay Gymnasium's bit for bit.
"""

from __future__ import annotations

import ctypes
import ctypes.util

_libm = ctypes.CDLL(ctypes.util.find_library("m"))
pow = _libm.pow
pow.argtypes = (ctypes.c_double, ctypes.c_double)
pow.restype = ctypes.c_double
powf = _libm.powf
powf.argtypes = (ctypes.c_float, ctypes.c_float)
powf.restype = ctypes.c_float
