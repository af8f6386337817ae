"""numpy arrays into Dr.Jit (transient_mi._upload): Dr.Jit 1.5's LLVM kernels read a mapped numpy buffer a whole
vector at a time, past its end; :func:`~transient_mi._upload.upload` pads the buffer, so a read past the data stays
inside it. Reproduced with a buffer that ends right before a page that is not mapped (a guard page), in a child
process: a read past its end is a segmentation fault, which must not take pytest down with it."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: The child: ``guarded(n, dtype)`` is a numpy array whose last byte is followed by a PROT_NONE page.
CHILD = r'''
import ctypes, mmap, sys
import numpy as np

def guarded(n, dtype):
    nbytes = n * np.dtype(dtype).itemsize
    page = mmap.PAGESIZE
    pages = -(-nbytes // page)
    buf = mmap.mmap(-1, (pages + 1) * page)
    addr = ctypes.addressof(ctypes.c_char.from_buffer(buf))
    assert ctypes.CDLL(None).mprotect(ctypes.c_void_p(addr + pages * page), page, 0) == 0
    a = np.frombuffer(buf, dtype=dtype, count=n, offset=pages * page - nbytes)
    a[:] = np.arange(n) % 251
    assert a.ctypes.data + nbytes == addr + pages * page  # the data ends where the guard page starts
    guarded.keep.append(buf)
    return a

guarded.keep = []
import transient_mi  # noqa: F401  (the variant)
import drjit as dr
import mitsuba as mi
from transient_mi._upload import upload, upload_tensor

mode = sys.argv[1]
types = {"float32": mi.Float, "uint32": mi.UInt32, "float64": mi.Float64}
for n in (1, 15, 17, 100, 129016):
    for name, T in types.items():
        a = guarded(n, name)
        x = T(a) if mode == "raw" else upload(T, a)
        y = x + dr.opaque(T, 0)
        dr.eval(y)
        dr.sync_thread()
        assert np.array_equal(np.asarray(y), a), (name, n)
    t = upload_tensor(guarded(n, "float32").reshape(n, 1))
    assert t.shape == (n, 1) and float(dr.sum(t.array + dr.opaque(mi.Float, 0))[0]) == float((np.arange(n) % 251).sum())
print("ok")
'''


def _child(mode: str, tmp_path: Path) -> subprocess.CompletedProcess:
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    return subprocess.run([sys.executable, str(script), mode], capture_output=True, text=True, cwd=ROOT, timeout=300)


def test_upload_never_reads_past_the_numpy_buffer(tmp_path):
    """float32, uint32 and float64 arrays of 1 to 129016 elements (not multiples of a vector), each ending right
    before a guard page, uploaded and read by a kernel: the child finishes with the exact values. The same arrays
    handed to the Dr.Jit constructors directly crash the child (signal 11): that shows the guard page catches a
    read past the end, so the first result means something (and when a Dr.Jit release stops reading past a mapped
    buffer, this fails: the padded copy may then go)."""
    safe = _child("upload", tmp_path)
    assert safe.returncode == 0 and safe.stdout.strip() == "ok", safe.stderr[-2000:]
    raw = _child("raw", tmp_path)
    assert raw.returncode == -11, (raw.returncode, raw.stdout[-500:], raw.stderr[-2000:])


def test_upload_converts_and_refuses_another_element_type():
    """Any array-like is flattened in C order and converted as numpy's ``astype`` (float64 -> float32 rounds to
    nearest, the same bytes); a ``dtype`` that is not the Dr.Jit type's own is refused."""
    import numpy as np
    import pytest

    import transient_mi  # noqa: F401  (first: the LLVM drjit needs)
    import mitsuba as mi
    from transient_mi._upload import upload

    a = np.random.default_rng(3).normal(size=(4, 5))
    assert np.asarray(upload(mi.Float, a)).tobytes() == a.astype(np.float32).ravel().tobytes()
    assert np.asarray(upload(mi.UInt32, [3, 1, 2])).tolist() == [3, 1, 2]
    assert np.asarray(upload(mi.Bool, [True, False])).tolist() == [True, False]
    with pytest.raises(TypeError, match="float64 is not the element type of Float"):
        upload(mi.Float, a, np.float64)


#: Dr.Jit array types a numpy array must not be handed to directly.
_ARRAY_TYPES = {"Float", "Float32", "Float64", "UInt32", "Int32", "UInt64", "Int64", "TensorXf", "TensorXd"}


def _looks_numpy(node: ast.AST) -> bool:
    """An expression that is a numpy array by its form: ``np.`` calls, ``.astype``/``.ravel``/``.reshape``/``.T``,
    or a subscript with a slice (a column ``a[:, i]``)."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.Attribute) and (sub.attr in {"astype", "ravel", "reshape", "T", "flatten"}
                                               or (isinstance(sub.value, ast.Name) and sub.value.id == "np")):
            return True
        if isinstance(sub, ast.Subscript) and any(isinstance(s, ast.Slice) for s in ast.walk(sub.slice)):
            return True
    return False


def test_no_numpy_array_reaches_drjit_but_through_upload():
    """No module of the package builds a Dr.Jit array from a numpy array by its constructor (``mi.Float(a.ravel())``,
    ``mi.TensorXf(h)``): every such array goes through :func:`~transient_mi._upload.upload`. By the source's form:
    any ``mi.TensorXf(...)`` call, and array constructors whose argument is a numpy expression (see
    :func:`_looks_numpy`)."""
    bad = []
    for f in sorted((ROOT / "transient_mi").rglob("*.py")):
        if f.name == "_upload.py":
            continue
        for node in ast.walk(ast.parse(f.read_text(), filename=str(f))):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and isinstance(node.func.value, ast.Name) and node.func.value.id in {"mi", "dr"}
                    and node.func.attr in _ARRAY_TYPES and node.args):
                continue
            if node.func.attr.startswith("Tensor") or _looks_numpy(node.args[0]):
                bad.append(f"{f.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)[:80]}")
    assert not bad, "numpy arrays handed to Dr.Jit directly (use transient_mi._upload.upload):\n" + "\n".join(bad)
