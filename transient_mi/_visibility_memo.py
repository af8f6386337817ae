"""Visibility masks kept between renders of one hidden geometry (the fits' forward model).

A fit renders the same mesh more than once: the carving fits one reflectance per face with the vertices held
(a forward and a reverse pass per evaluation of its objective, :mod:`transient_mi.fit.mesh_carve`), and every
reverse pass of the vertex stage (Adam) follows a forward pass at the same vertices. The deterministic
estimator's visibility (:func:`~transient_mi.integrators._nlos_surfaces.visibility_masks`: Mitsuba's shadow-ray
tests from the laser spots and the wall's cells to every element's samples) depends on the scene's geometry and the
rays alone, not on reflectances, blurs or the adjoint, so those renders traced the same rays again: about a third
of a carving evaluation's time on the letter's 8 x 8 capture (``bench/bench_visibility_memo.py``, docs/fit.md).

A :class:`VisibilityMemo`, made active around a render (:meth:`VisibilityMemo.active`), keeps each call's masks
under a digest of the call's inputs (the ray origins, the wall normal, the elements' samples, the pairs asked
for, the layout) and of the scene's geometry, which its owner states with :meth:`VisibilityMemo.set_geometry`
(the :class:`~transient_mi.fit.capture_model.CaptureModel` owns its scene and moves nothing but its model mesh: it
states the mesh's vertices). A new geometry forgets every mask. A mask taken from the memo is the traced one's
bytes: a ray's result does not depend on the launch it is traced in (as
:class:`~transient_mi.integrators._nlos_pairs.TracedVisibility` relies on), so a render with the memo equals one
without, bit for bit (``tests/test_visibility_memo.py``).

Outside an active memo (every ``mi.render`` and ``transient-mi render``) nothing is kept: a scene a user changes
between renders (a shape moved through ``mi.traverse``) has no owner to state its geometry.

The module lives outside ``transient_mi.integrators`` on purpose: a variant change re-imports every module of the
plug-in sub-packages (:mod:`transient_mi._registry`), and a second copy of this one would hold a second context
variable, which the capture model would set and the quadrature would not read.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib

import numpy as np

__all__ = ["VisibilityMemo", "current"]

#: The most mask bytes one memo keeps (beyond it, new masks are traced and not kept).
MAX_BYTES = 512 * 2 ** 20

_ACTIVE: contextvars.ContextVar = contextvars.ContextVar("nlos_visibility_memo", default=None)


def current() -> "VisibilityMemo | None":
    """The memo active in this context (:meth:`VisibilityMemo.active`), or None."""
    return _ACTIVE.get()


def _digest(*parts) -> bytes:
    h = hashlib.blake2b(digest_size=20)
    for p in parts:
        if isinstance(p, np.ndarray):
            a = np.ascontiguousarray(p)
            h.update(str((a.dtype.str, a.shape)).encode())
            h.update(a.data)
        else:
            h.update(repr(p).encode())
        h.update(b"|")
    return h.digest()


class VisibilityMemo:
    """Visibility masks of one scene geometry (module docstring). ``hits`` and ``misses`` count the calls served
    from the memo and traced since the memo was made."""

    def __init__(self, max_bytes: int = MAX_BYTES):
        self.max_bytes = int(max_bytes)
        self._geometry: bytes | None = None
        self._masks: dict[bytes, np.ndarray] = {}
        self._bytes = 0
        self.hits = self.misses = 0

    def set_geometry(self, *arrays) -> None:
        """State the scene's geometry (arrays whose bytes determine every shape's position, e.g. the model mesh's
        vertices as the scene holds them); masks of another geometry are forgotten."""
        key = _digest(*[np.asarray(a) for a in arrays])
        if key != self._geometry:
            self._geometry = key
            self._masks.clear()
            self._bytes = 0

    @contextlib.contextmanager
    def active(self):
        """Serve :func:`~transient_mi.integrators._nlos_surfaces.visibility_masks` from this memo inside the ``with``
        block (this thread and context only)."""
        token = _ACTIVE.set(self)
        try:
            yield self
        finally:
            _ACTIVE.reset(token)

    def key(self, scene, origins, normal, samples, pairs, element_major: bool) -> bytes | None:
        """The digest of one :func:`~transient_mi.integrators._nlos_surfaces.visibility_masks` call (None before a
        geometry is stated)."""
        if self._geometry is None:
            return None
        return _digest(self._geometry, id(scene), np.asarray(origins, dtype=np.float64),
                       np.asarray(normal, dtype=np.float64), np.asarray(samples, dtype=np.float64),
                       None if pairs is None else np.asarray(pairs), bool(element_major))

    def get(self, key: bytes | None) -> np.ndarray | None:
        """A copy of the masks kept under ``key``, or None (counted as a miss)."""
        m = None if key is None else self._masks.get(key)
        if m is None:
            self.misses += 1
            return None
        self.hits += 1
        return m.copy()

    def put(self, key: bytes | None, masks: np.ndarray) -> None:
        """Keep a copy of ``masks`` under ``key`` (unless that would pass :attr:`max_bytes`)."""
        if key is None or key in self._masks or self._bytes + masks.nbytes > self.max_bytes:
            return
        self._masks[key] = masks.copy()
        self._bytes += masks.nbytes
