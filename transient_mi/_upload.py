"""numpy arrays into Dr.Jit's own memory: the one way the package hands numpy data to Dr.Jit.

**Why not ``mi.Float(array)``.** Dr.Jit 1.5 maps a C-contiguous numpy array of its own element type without a copy,
and its LLVM kernels read such an input a whole vector at a time (16 lanes with AVX-512), up to the end of the
vector that holds the array's last element: as many as 15 elements past the array's end. Dr.Jit pads the memory it
allocates itself, but not a numpy buffer. The C library places a large buffer (over 128 KiB) in its own memory
mapping, a few bytes before the mapping's last page ends; when the next page is not mapped, that read is a
segmentation fault. It depends on the array's length and on the process's memory layout, so it is rare and not
repeatable: a dataset worker died of it in ``dr.eval`` of such a copy (``tests/test_upload.py`` reproduces it with a
guard page after the buffer).

:func:`upload` copies the data into a numpy buffer :data:`PAD_ELEMENTS` elements longer, lets Dr.Jit read the
leading part (its vector reads stay inside the buffer), and copies that into Dr.Jit's memory by a real operation
(``dr.copy`` returns the mapped buffer). The copy has run when :func:`upload` returns (``dr.sync_thread``: the LLVM
backend launches it asynchronously), so the numpy buffer may be freed. A copy of its own also keeps the kernels the
same: a mapped buffer is loaded with its own alignment, which varies between calls and would recompile the kernel
that reads it at every call.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

#: Elements of slack after the data (a vector of the widest Dr.Jit LLVM backend, 16 lanes, four times over).
PAD_ELEMENTS = 64

_NUMPY_TYPES = {
    dr.VarType.Bool: np.bool_, dr.VarType.Int32: np.int32, dr.VarType.UInt32: np.uint32,
    dr.VarType.Int64: np.int64, dr.VarType.UInt64: np.uint64, dr.VarType.Float32: np.float32,
    dr.VarType.Float64: np.float64,
}


def numpy_type(T) -> type:
    """The numpy element type of the flat Dr.Jit array type ``T`` (``mi.Float``: ``np.float32``)."""
    vt = dr.type_v(T)
    if vt not in _NUMPY_TYPES:
        raise TypeError(f"upload: no numpy type for the Dr.Jit type {T.__name__} ({vt})")
    return _NUMPY_TYPES[vt]


def upload(T, a, dtype=None):
    """``a`` (any array-like, any shape: flattened in C order) as a Dr.Jit array of the flat type ``T`` in Dr.Jit's
    own memory, evaluated (see the module docstring). ``dtype``, optional: the numpy type ``a`` is converted to first
    (default ``T``'s own; another one must be ``T``'s too). Values are converted as numpy's ``astype`` does."""
    want = numpy_type(T)
    if dtype is not None and np.dtype(dtype) != np.dtype(want):
        raise TypeError(f"upload: {np.dtype(dtype).name} is not the element type of {T.__name__} "
                        f"({np.dtype(want).name})")
    src = np.asarray(a)
    n = src.size
    buf = np.zeros(n + PAD_ELEMENTS, dtype=want)
    buf[:n] = src.reshape(-1)
    x = T(buf[:n]) | dr.opaque(T, False) if want is np.bool_ else T(buf[:n]) + dr.opaque(T, 0)
    dr.eval(x)
    dr.sync_thread()
    del buf
    return x


def upload_tensor(a, T=None):
    """``a`` as a Dr.Jit tensor of its shape (``T`` default ``mi.TensorXf``, float32), its data by :func:`upload`."""
    T = mi.TensorXf if T is None else T
    a = np.asarray(a)
    return T(upload(dr.array_t(T), a), a.shape)
