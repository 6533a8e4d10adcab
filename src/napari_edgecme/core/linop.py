"""Linear operators that compose: ``A @ B``, ``A.T``, ``A + B``, ``A - B``, ``c * A``.

Every linear map of the engine -- the blurs ``T`` of paper Eq. 8
(:mod:`~napari_edgecme.core.operators`), the crop ``M`` of the masked data terms
(Eqs. 19, 21), the finite differences ``D``, the measurement matrix of Eqs. 13-15,
the normal operators the solvers invert -- is a :class:`LinearOperator`: array
shapes of its domain and range, a forward map and its exact adjoint. Operators
combine into new operators, so a normal operator is written as in the paper,

.. code-block:: python

    data = Crop(domain_shape, inner) @ blur  # M T
    normal = lam * (data.T @ data) + beta * (gradient.T @ gradient)

and :func:`~napari_edgecme.core.cg.conjugate_gradient` and FISTA
(through :class:`~napari_edgecme.core.lasso.QuadraticTerm`) take operators. Because
every adjoint is an operator's ``adjoint``, one parametrised dot test
(:func:`dottest`, ``tests/core/test_operators.py``) covers all of them, compositions
included. In the manner of SigPy's ``linop`` (see ``STYLE.md``).

Applying an operator is ``A @ x`` (``A.forward(x)``) and its adjoint ``A.T @ y``
(``A.adjoint(y)``); inputs of the wrong shape are refused with a message naming the
operator, and are cast to the operator's dtype. Combinations never modify their
inputs or the results of their parts in place, and never fold scale factors, so a
combined operator gives the same floating-point result as the same steps written
by hand.
"""

from __future__ import annotations

import numbers

import numpy as np
from scipy import sparse

__all__ = [
    "Adjoint",
    "Composition",
    "Crop",
    "LinearOperator",
    "MatrixOperator",
    "Scaled",
    "Sum",
    "dottest",
]


class LinearOperator:
    """A linear map between arrays with its exact adjoint.

    Subclasses set the attributes below and implement ``_forward`` and ``_adjoint``
    on arrays already checked and cast.

    Attributes
    ----------
    shape_in, shape_out : tuple of int
        Array shapes of the domain and the range.
    dtype : numpy.dtype
        float32 or float64; inputs are cast to it.
    """

    shape_in: tuple[int, ...]
    shape_out: tuple[int, ...]
    dtype: np.dtype

    #: NumPy defers to the operator's own ``*`` and ``@`` (``np.float32(2) * A`` is ``Scaled``)
    __array_ufunc__ = None

    def forward(self, x: np.ndarray) -> np.ndarray:
        """``A x``: array of ``shape_in`` -> array of ``shape_out``."""
        return self._forward(self._check(x, self.shape_in, "x"))

    def adjoint(self, y: np.ndarray) -> np.ndarray:
        """``A^T y``: array of ``shape_out`` -> array of ``shape_in``."""
        return self._adjoint(self._check(y, self.shape_out, "y"))

    @property
    def T(self) -> LinearOperator:
        """The adjoint operator ``A^T`` (``A.T.T`` is ``A``)."""
        return Adjoint(self)

    def __matmul__(self, other):
        """``A @ B`` (an operator: B first, then A) or ``A @ x`` (the array ``A x``)."""
        if isinstance(other, LinearOperator):
            return Composition(self, other)
        return self.forward(other)

    def __add__(self, other):
        if not isinstance(other, LinearOperator):
            return NotImplemented
        return Sum(self, other)

    def __sub__(self, other):
        if not isinstance(other, LinearOperator):
            return NotImplemented
        return Sum(self, Scaled(other, -1.0))

    def __neg__(self):
        return Scaled(self, -1.0)

    def __mul__(self, scale):
        if not isinstance(scale, numbers.Real):
            return NotImplemented
        return Scaled(self, scale)

    __rmul__ = __mul__

    def __repr__(self) -> str:
        return (f"<{type(self).__name__} {self.shape_in} -> {self.shape_out}, "
                f"{np.dtype(self.dtype).name}>")

    def _check(self, arr, shape, name) -> np.ndarray:
        arr = np.asarray(arr)
        if arr.shape != tuple(shape):
            raise ValueError(
                f"{type(self).__name__}: {name} must have shape {tuple(shape)}; got {arr.shape}"
            )
        return arr.astype(self.dtype, copy=False)

    def _forward(self, x):  # pragma: no cover - abstract
        raise NotImplementedError

    def _adjoint(self, y):  # pragma: no cover - abstract
        raise NotImplementedError


def dottest(op: LinearOperator, rng=None) -> float:
    """Relative mismatch of ``<A x, y>`` and ``<x, A^T y>`` for random ``x``, ``y``.

    An exact adjoint gives round-off only (about 1e-6 in float32, 1e-14 in float64).
    """
    rng = np.random.default_rng(rng)
    x = rng.standard_normal(op.shape_in).astype(op.dtype)
    y = rng.standard_normal(op.shape_out).astype(op.dtype)
    lhs = np.vdot(op.forward(x).astype(np.float64), y.astype(np.float64))
    rhs = np.vdot(x.astype(np.float64), op.adjoint(y).astype(np.float64))
    return float(abs(lhs - rhs) / max(abs(lhs), abs(rhs), 1e-30))


# --------------------------------------------------------------------------------------
# the algebra
# --------------------------------------------------------------------------------------

class Adjoint(LinearOperator):
    """``A^T``: forward is ``A``'s adjoint and adjoint its forward (``A.T``)."""

    def __init__(self, op: LinearOperator):
        self.op = op
        self.shape_in, self.shape_out, self.dtype = op.shape_out, op.shape_in, op.dtype

    @property
    def T(self) -> LinearOperator:
        return self.op

    def _forward(self, x):
        return self.op.adjoint(x)

    def _adjoint(self, y):
        return self.op.forward(y)


class Composition(LinearOperator):
    """``A B``: ``B`` first, then ``A`` (``A @ B``); the adjoint is ``B^T A^T``.

    Parameters
    ----------
    outer, inner : LinearOperator
        ``A`` and ``B``, with ``inner.shape_out == outer.shape_in``.
    """

    def __init__(self, outer: LinearOperator, inner: LinearOperator):
        if tuple(inner.shape_out) != tuple(outer.shape_in):
            raise ValueError(f"cannot compose {outer!r} after {inner!r}: the inner range "
                             f"{inner.shape_out} is not the outer domain {outer.shape_in}")
        self.outer, self.inner = outer, inner
        self.shape_in, self.shape_out = inner.shape_in, outer.shape_out
        self.dtype = np.result_type(outer.dtype, inner.dtype)

    def _forward(self, x):
        return self.outer.forward(self.inner.forward(x))

    def _adjoint(self, y):
        return self.inner.adjoint(self.outer.adjoint(y))


class Sum(LinearOperator):
    """``A + B`` on a common domain and range (``A + B``; ``A - B`` is ``A + (-1) B``)."""

    def __init__(self, first: LinearOperator, second: LinearOperator):
        if (tuple(first.shape_in), tuple(first.shape_out)) != (tuple(second.shape_in),
                                                               tuple(second.shape_out)):
            raise ValueError(f"cannot add {first!r} and {second!r}: shapes differ")
        self.first, self.second = first, second
        self.shape_in, self.shape_out = first.shape_in, first.shape_out
        self.dtype = np.result_type(first.dtype, second.dtype)

    def _forward(self, x):
        return self.first.forward(x) + self.second.forward(x)

    def _adjoint(self, y):
        return self.first.adjoint(y) + self.second.adjoint(y)


class Scaled(LinearOperator):
    """``c A`` for a real scalar ``c`` (``c * A``), ``c`` cast to the operator's dtype."""

    def __init__(self, op: LinearOperator, scale: float):
        self.op = op
        self.shape_in, self.shape_out, self.dtype = op.shape_in, op.shape_out, op.dtype
        self.scale = np.dtype(op.dtype).type(scale)

    def _forward(self, x):
        return self.scale * self.op.forward(x)

    def _adjoint(self, y):
        return self.scale * self.op.adjoint(y)


# --------------------------------------------------------------------------------------
# generic operators
# --------------------------------------------------------------------------------------

class Crop(LinearOperator):
    """The crop ``M`` to a rectangle: (H, W) -> (h, w); the adjoint zero-fills.

    The mask of the masked data terms (Eqs. 19, 21 and the deconvolution's data term):
    only the observed pixels of a latent domain padded beyond them are compared with
    the data. ``M M^T`` is the identity, ``M^T M`` the diagonal 0/1 mask.

    Parameters
    ----------
    shape : tuple of int
        ``(H, W)``, the domain.
    box : tuple of slice
        The kept rectangle ``(rows, cols)`` inside the domain (steps of one).
    dtype : dtype
        float32 or float64.

    Notes
    -----
    ``forward`` returns a view of its input (no copy), as slicing does.
    """

    def __init__(self, shape, box, dtype=np.float32):
        self.shape_in = tuple(int(s) for s in shape)
        self.box = tuple(slice(*sl.indices(n)[:2]) for sl, n in zip(box, self.shape_in,
                                                                    strict=True))
        self.shape_out = tuple(sl.stop - sl.start for sl in self.box)
        self.dtype = np.dtype(dtype)

    def _forward(self, x):
        return x[self.box]

    def _adjoint(self, y):
        out = np.zeros(self.shape_in, self.dtype)
        out[self.box] = y
        return out


class MatrixOperator(LinearOperator):
    """A matrix (dense or scipy.sparse) as an operator: (n,) -> (m,), ``x -> A x``.

    Parameters
    ----------
    matrix : ndarray or scipy.sparse matrix of shape (m, n)
        Float32 or float64 (anything else is converted to float64).
    """

    def __init__(self, matrix):
        if sparse.issparse(matrix):
            self.matrix = matrix.tocsr()
            #: the transpose, built once (CSR: a row per column of ``matrix``)
            self._transpose = self.matrix.T.tocsr()
        else:
            self.matrix = np.asarray(matrix)
            self._transpose = self.matrix.T
        dtype = self.matrix.dtype
        self.dtype = dtype if dtype in (np.float32, np.float64) else np.dtype(np.float64)
        if self.matrix.dtype != self.dtype:
            self.matrix = self.matrix.astype(self.dtype)
            self._transpose = self._transpose.astype(self.dtype)
        m, n = self.matrix.shape
        self.shape_in, self.shape_out = (n,), (m,)

    def _forward(self, x):
        return self.matrix @ x

    def _adjoint(self, y):
        return self._transpose @ y
