"""Sparse Cholesky factorisation by SuiteSparse CHOLMOD (supernodal), the copy that ``cvxopt`` ships.

``cvxopt.cholmod`` itself converts a scipy matrix only through triplets (30-45 ms for the 0.4-0.7M entries of
the fill's larger systems, as long as a factorisation) and keeps the interpreter's lock for the whole
factorisation (two at once take as long as one after the other), while the hole fill runs its solves two at
a time. So CHOLMOD's own functions are called here through ``ctypes``, from the library ``cvxopt.cholmod``
has loaded: on scipy's CSC arrays as they are (no copy), each call with its own CHOLMOD ``Common``, and the
lock released while CHOLMOD works (``ctypes`` does that for every foreign call).

The ``Common`` fields set here are found by their offsets in CHOLMOD 3.0's ``cholmod_common`` (cvxopt 1.3.3
ships CHOLMOD 3.0.6); :func:`available` checks that ``cholmod_start`` left the documented defaults at those
offsets, and is False where it did not (or cvxopt is missing): the callers then factorise by SuperLU.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np
from scipy import sparse

#: Bytes reserved for ``cholmod_common`` (its size in CHOLMOD 3.0 is about 2.6 KB; room to spare).
_COMMON_BYTES = 16384

# cholmod_common offsets (x86-64, CHOLMOD 3.0 cholmod_core.h): the defaults that cholmod_start writes there
_GROW0, _SUPERNODAL_SWITCH, _SUPERNODAL, _ZRELAX0, _NRELAX2 = 8, 40, 48, 80, 120
_PRINT, _NMETHODS = 144, 168
_METHOD0, _METHOD_BYTES, _ORDERING_IN_METHOD, _PRUNE_DENSE_IN_METHOD = 184, 168, 132, 16
_POSTORDER = _METHOD0 + 10 * _METHOD_BYTES  # after the 10 ordering methods

#: CHOLMOD's ordering codes (cholmod_core.h).
NATURAL, AMD = 0, 2
_CHOLMOD_A = 0  # cholmod_solve: A x = b


class _Sparse(ctypes.Structure):
    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("p", ctypes.c_void_p), ("i", ctypes.c_void_p), ("nz", ctypes.c_void_p),
                ("x", ctypes.c_void_p), ("z", ctypes.c_void_p), ("stype", ctypes.c_int),
                ("itype", ctypes.c_int), ("xtype", ctypes.c_int), ("dtype", ctypes.c_int),
                ("sorted", ctypes.c_int), ("packed", ctypes.c_int)]


class _Dense(ctypes.Structure):
    _fields_ = [("nrow", ctypes.c_size_t), ("ncol", ctypes.c_size_t), ("nzmax", ctypes.c_size_t),
                ("d", ctypes.c_size_t), ("x", ctypes.c_void_p), ("z", ctypes.c_void_p),
                ("xtype", ctypes.c_int), ("dtype", ctypes.c_int)]


class _FactorHead(ctypes.Structure):  # the first fields of cholmod_factor
    _fields_ = [("n", ctypes.c_size_t), ("minor", ctypes.c_size_t)]


class NotPositiveDefinite(ArithmeticError):
    """CHOLMOD met a pivot that is not positive: the matrix is not (numerically) positive definite."""


@functools.cache
def _library():
    """CHOLMOD's functions (int version), or None where cvxopt is missing or its CHOLMOD is not the expected one."""
    try:
        import cvxopt.cholmod as module  # loads libcholmod and the libraries it needs
        lib = ctypes.CDLL(module.__file__)  # its symbols are looked up in the libraries it needs too
        vp = ctypes.c_void_p
        for name, res, args in [("cholmod_start", ctypes.c_int, [vp]), ("cholmod_finish", ctypes.c_int, [vp]),
                                ("cholmod_analyze", vp, [vp, vp]),
                                ("cholmod_factorize", ctypes.c_int, [vp, vp, vp]),
                                ("cholmod_solve", vp, [ctypes.c_int, vp, vp, vp]),
                                ("cholmod_free_factor", ctypes.c_int, [vp, vp]),
                                ("cholmod_free_dense", ctypes.c_int, [vp, vp])]:
            f = getattr(lib, name)
            f.restype, f.argtypes = res, args
    except (ImportError, OSError, AttributeError):
        return None
    common = ctypes.create_string_buffer(_COMMON_BYTES)
    if not lib.cholmod_start(common):
        return None
    ok = _defaults_in_place(common)
    lib.cholmod_finish(common)
    return lib if ok else None


def _at(common, offset: int, ctype):
    return ctype.from_buffer(common, offset)


def _defaults_in_place(common) -> bool:
    """Whether ``cholmod_start`` left CHOLMOD 3.0's defaults at the offsets this module writes to."""
    d, i, z = ctypes.c_double, ctypes.c_int, ctypes.c_size_t
    method1 = _METHOD0 + _METHOD_BYTES
    return (_at(common, _GROW0, d).value == 1.2 and _at(common, _SUPERNODAL_SWITCH, d).value == 40.0
            and _at(common, _SUPERNODAL, i).value == 1 and _at(common, _ZRELAX0, d).value == 0.8
            and _at(common, _NRELAX2, z).value == 48 and _at(common, _PRINT, i).value == 3
            and _at(common, _NMETHODS, i).value == 0
            and _at(common, _METHOD0 + _PRUNE_DENSE_IN_METHOD, d).value == 10.0
            and _at(common, _METHOD0 + _ORDERING_IN_METHOD, i).value == 1  # CHOLMOD_GIVEN
            and _at(common, method1 + _ORDERING_IN_METHOD, i).value == AMD
            and _at(common, _POSTORDER, i).value == 1)


def available() -> bool:
    """Whether :func:`spd_solve` can run (cvxopt installed, with the CHOLMOD this module was written for)."""
    return _library() is not None


def spd_solve(A: sparse.spmatrix, b: np.ndarray, ordering: int = AMD) -> np.ndarray:
    """Solve A x = b for a symmetric positive definite sparse A by a supernodal Cholesky factorisation.

    Parameters
    ----------
    A : (n, n) sparse, symmetric (both triangles stored; only the upper one is read).
    b : float (n,) right-hand side.
    ordering : :data:`AMD` (approximate minimum degree) or :data:`NATURAL` (A's rows and columns are in
        elimination order already); followed by CHOLMOD's postorder of the elimination tree either way.

    Returns
    -------
    float64 (n,): the solution.

    Raises
    ------
    NotPositiveDefinite : where a pivot is not positive (nothing is returned: the caller decides).
    RuntimeError : where CHOLMOD is not available or fails otherwise (out of memory).
    """
    lib = _library()
    if lib is None:
        raise RuntimeError("CHOLMOD (cvxopt) is not available")
    A = sparse.csc_matrix(A)
    n = A.shape[0]
    b = np.ascontiguousarray(b, dtype=np.float64)
    if n == 0:
        return np.zeros(0)
    A.sort_indices()
    indptr, indices = A.indptr.astype(np.int32, copy=False), A.indices.astype(np.int32, copy=False)
    data = np.ascontiguousarray(A.data, dtype=np.float64)
    # stype +1: the upper triangle (CHOLMOD orders and factorises fastest from it); itype int, xtype real, double
    mat = _Sparse(n, n, data.size, indptr.ctypes.data, indices.ctypes.data, None, data.ctypes.data, None,
                  1, 0, 1, 0, 1, 1)
    rhs = _Dense(n, 1, n, n, b.ctypes.data, None, 1, 0)
    common = ctypes.create_string_buffer(_COMMON_BYTES)
    lib.cholmod_start(common)
    factor = ctypes.c_void_p()
    solution = ctypes.c_void_p()
    try:
        _at(common, _PRINT, ctypes.c_int).value = 0  # no messages on stdout: the caller is told by the exception
        _at(common, _SUPERNODAL, ctypes.c_int).value = 2  # supernodal always (the fill's systems are large)
        _at(common, _NMETHODS, ctypes.c_int).value = 1  # this one ordering, no trial of others
        _at(common, _METHOD0 + _ORDERING_IN_METHOD, ctypes.c_int).value = ordering
        factor.value = lib.cholmod_analyze(ctypes.byref(mat), common)
        if not factor.value:
            raise RuntimeError("CHOLMOD's analysis failed")
        if not lib.cholmod_factorize(ctypes.byref(mat), factor, common):
            raise RuntimeError("CHOLMOD's factorisation failed")
        head = _FactorHead.from_address(factor.value)
        if head.minor < head.n:
            raise NotPositiveDefinite(f"not positive definite at column {head.minor} of {head.n}")
        solution.value = lib.cholmod_solve(_CHOLMOD_A, factor, ctypes.byref(rhs), common)
        if not solution.value:
            raise RuntimeError("CHOLMOD's solve failed")
        x = np.empty(n)
        ctypes.memmove(x.ctypes.data, _Dense.from_address(solution.value).x, n * 8)
        return x
    finally:
        if solution.value:
            lib.cholmod_free_dense(ctypes.byref(solution), common)
        if factor.value:
            lib.cholmod_free_factor(ctypes.byref(factor), common)
        lib.cholmod_finish(common)
