"""The compiled ground: the project's ``jit`` decorator and per-run quaternion kernels.

Compilation policy
------------------
Every compiled function of the project is made with :func:`jit` (or :func:`jit_parallel` for
the batch entry points), i.e. ``numba.njit`` with

* ``cache=True``: machine code is kept on disk and loaded by later processes;
* ``fastmath=False``: no reassociation, no fused multiply-add contraction, IEEE semantics for
  NaN and infinities, so a run is reproducible and equal to itself on every path (node step,
  offline run, run ``k`` of a campaign) bit for bit;
* ``error_model="numpy"``: a division by zero gives ``inf``/``nan`` as numpy does, instead of
  raising ``ZeroDivisionError`` (and no per-division check in the machine code).

Compiled kernels call the system ``libm`` for ``exp``, ``tanh``, ``pow``, ``expm1``, ``atan``,
while numpy uses its own SIMD routines even for one element: results agree with the numpy
formulas of the same operations to the last bit or two (about 1e-16 relative per call, ~1e-13
over a closed-loop run), not bitwise.

Cache location
--------------
numba keeps compiled machine code on disk, keyed on each function's own source file.  A compiled
function that calls a kernel of another module would therefore keep running the old kernel after
that module changed, so this module chooses the cache directory, **before** any kernel is compiled,
as ``<base>/numba/sappc-<digest>``, where ``<digest>`` hashes the sources of every module in
:data:`KERNEL_MODULES`: any edit of any kernel starts a fresh cache (a recompile of about a
minute), an unchanged install loads the old one.  ``<base>`` is ``$SAPPC_CACHE_DIR``, else
``$XDG_CACHE_HOME/sappc``, else ``~/.cache/sappc``: a user directory, so a read-only install
works.  The choice is exported as ``NUMBA_CACHE_DIR`` (child processes, e.g. ROS nodes and
campaign workers, inherit it) and is :data:`CACHE_DIR`.

Quaternion kernels
------------------
The convention is that of :mod:`gnc_common.attitude`: scalar last ``(x, y, z, w)``, Hamilton
product.  Each kernel works on one run's small float64 arrays (length 3 or 4) and writes into an
``out`` array supplied by the caller (no allocation per call); ``out`` may not alias an input
unless the docstring says so.  The operations are written in the same order as the numpy
functions of :mod:`gnc_common.attitude` (e.g. ``dot = (a0 b0 + a1 b1) + a2 b2``), so the two
agree bit for bit wherever no transcendental function is involved.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CACHE_DIR",
    "KERNEL_MODULES",
    "kernel_sources_digest",
    "cross3",
    "dcm_BR_times",
    "dcm_BR_times_of",
    "dot3",
    "error_quaternion",
    "error_quaternion_of",
    "gamma_inverse_of",
    "gamma_inverse_times",
    "inverse3",
    "inverse3_stack",
    "jit",
    "jit_parallel",
    "matvec3",
    "matvec3_of",
    "matvec3_flat",
    "matvec3_flat_of",
    "quat_conjugate",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
    "quat_rotate_of",
]


#: The modules that hold compiled functions, which call one another.  numba keys a cached function
#: on its own source file only, so a cached function that calls a kernel of another module would
#: survive an edit of that kernel; the cache directory is therefore named by a digest of all of
#: them (``tests/test_layering.py`` checks that every module using :func:`jit` is listed).
KERNEL_MODULES = ("gnc_common.compiled", "gnc_common.libm", "gnc_common.ephemeris", "sappc_controller.core.kernels", "gnc_common.input_check", "sappc_estimator.core.mekf",
                  "spacecraft_sim.core.kernels", "sappc.offline.compiled_loop", "sappc.evaluation.metrics", "spacecraft_sim.core.wheels",
                  "spacecraft_sim.core.sensors", "spacecraft_sim.core.orbit", "spacecraft_sim.core.magnetic_field",
                  "spacecraft_sim.core.magnetorquers", "spacecraft_sim.core.environment", "sappc_momentum.core.law", "sappc_momentum.core.predictive",
                  "spacecraft_sim.core.magnetometer", "sappc_modes.core.modes", "sappc_modes.core.bdot",
                  "sappc.offline.lanes")
#: Set to ``0``, :mod:`gnc_common.libm` declares no libmvec variant (every SIMD lane calls the
#: scalar libm function); part of the cache directory's name.
LIBMVEC_ENV = "SAPPC_LIBMVEC"
#: Characters of the sources' SHA-256 digest in the cache directory's name.
_DIGEST_CHARS = 16


def kernel_sources_digest() -> str:
    """SHA-256 (first :data:`_DIGEST_CHARS` hex digits) of the sources of :data:`KERNEL_MODULES`.

    The files are found next to this package (the same ``src/`` or ``site-packages``), without
    importing them.
    """
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for name in KERNEL_MODULES:
        h.update(name.encode())
        h.update((root / Path(*name.split(".")).with_suffix(".py")).read_bytes())
    # the one setting the machine code depends on beyond the sources and the CPU (numba's cache keys on
    # the CPU itself): whether gnc_common.libm declares libmvec's variants
    h.update(f"libmvec={os.environ.get(LIBMVEC_ENV, '1') != '0'}".encode())
    return h.hexdigest()[:_DIGEST_CHARS]


def _choose_cache_dir() -> str:
    """``NUMBA_CACHE_DIR`` for this process: ``<base>/numba/sappc-<digest of the kernel sources>``
    with ``<base>`` = ``$SAPPC_CACHE_DIR``, else ``$XDG_CACHE_HOME/sappc``, else ``~/.cache/sappc``
    (a user directory: it works from a read-only install).  A child process that inherits the
    same directory keeps it."""
    name = f"sappc-{kernel_sources_digest()}"
    inherited = os.environ.get("NUMBA_CACHE_DIR")
    if inherited and Path(inherited).name == name:
        return inherited
    base = os.environ.get("SAPPC_CACHE_DIR") or os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "sappc")
    path = os.path.join(base, "numba", name)
    os.makedirs(path, exist_ok=True)
    os.environ["NUMBA_CACHE_DIR"] = path
    return path


#: The numba cache directory used by this process (and inherited by its children).
CACHE_DIR: str = _choose_cache_dir()

_OPTIONS: dict[str, Any] = {"cache": True, "fastmath": False, "error_model": "numpy", "nogil": True}


#: Whether numba was imported before :data:`CACHE_DIR` was exported (its configuration is then re-read).
_NUMBA_IMPORTED_BEFORE = "numba" in sys.modules


def numba_module() -> Any:
    """``numba``, imported on first use, after :data:`CACHE_DIR` is exported (numba reads it).

    Importing a kernel module does not import numba (about 0.4 s, with the scipy linear algebra
    that numba loads): a command that calls no kernel (``sappc report``, ``--help``) never pays it."""
    global _NUMBA_IMPORTED_BEFORE
    import numba

    if _NUMBA_IMPORTED_BEFORE:
        _NUMBA_IMPORTED_BEFORE = False
        numba.core.config.reload_config()
    from gnc_common import libm

    libm.install()  # libmvec loaded before any kernel is compiled or loaded (gnc_common.libm)
    return numba


class LazyKernel:
    """A compiled function made on first use: the numba dispatcher of ``py_func`` with ``options``
    is created (numba imported, the machine code loaded from the cache or compiled) when the
    kernel is first called or asked for a dispatcher's attribute; every attribute then is the
    dispatcher's.  numba types it as that dispatcher (``_numba_type_``) where another kernel calls
    it, and inlines it (``targetoptions``, ``py_func``) as it would the dispatcher.  The results are
    the dispatcher's: it is the same compiled code."""


    def __init__(self, py_func: Any, options: dict[str, Any], signature: Any = None) -> None:
        self._dispatcher: Any = None  # first: __getattr__ reads it
        self.py_func = py_func
        self.options = (options, signature)
        self.__name__ = py_func.__name__
        self.__qualname__ = py_func.__qualname__
        self.__module__ = py_func.__module__
        self.__doc__ = py_func.__doc__
        self.__wrapped__ = py_func

    @property
    def dispatcher(self) -> Any:
        """The numba dispatcher (made now if it was not yet)."""
        d = self._dispatcher
        if d is None:
            options, signature = self.options
            njit = numba_module().njit
            d = self._dispatcher = njit(signature, **options)(self.py_func) if signature is not None else njit(**options)(self.py_func)
        return d

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        d = self._dispatcher
        return (d if d is not None else self.dispatcher)(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.dispatcher, name)

    def __repr__(self) -> str:
        return f"<LazyKernel {self.__module__}.{self.__qualname__}>"


def jit(*args, **kwargs):
    """``numba.njit`` with the project's options (module docstring); usable bare, with options or
    with an explicit signature.  The dispatcher is made on first use (:class:`LazyKernel`)."""
    options = {**_OPTIONS, **kwargs}
    if args and callable(args[0]) and len(args) == 1:
        return LazyKernel(args[0], options)
    signature = args[0] if args else None
    return lambda func: LazyKernel(func, options, signature)


def jit_parallel(func):
    """:func:`jit` with ``parallel=True`` for batch entry points (``prange`` over runs)."""
    return LazyKernel(func, {**_OPTIONS, "parallel": True})


# ----------------------------------------------------------------------------- vectors


@jit
def dot3(a, b):
    """``(a0 b0 + a1 b1) + a2 b2`` (the order of :func:`gnc_common.attitude.dot`)."""
    return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]


@jit
def cross3(a, b, out):
    """``out = a × b`` for 3-vectors."""
    c0 = a[1] * b[2] - a[2] * b[1]
    c1 = a[2] * b[0] - a[0] * b[2]
    c2 = a[0] * b[1] - a[1] * b[0]
    out[0] = c0
    out[1] = c1
    out[2] = c2


@jit
def matvec3_of(M, v0, v1, v2):
    """``M v`` for a (3, 3) matrix and ``v = (v0, v1, v2)``, summed ``(M_i0 v0 + M_i1 v1) + M_i2 v2``
    (as :func:`gnc_common.attitude.matvec`; for a diagonal ``M`` the zero terms are exact), as a
    3-tuple (scalars: no array view, so no reference count, in the loops that call it)."""
    return ((M[0, 0] * v0 + M[0, 1] * v1) + M[0, 2] * v2, (M[1, 0] * v0 + M[1, 1] * v1) + M[1, 2] * v2,
            (M[2, 0] * v0 + M[2, 1] * v1) + M[2, 2] * v2)


@jit
def matvec3(M, v, out):
    """:func:`matvec3_of` of ``v`` (3,) into ``out`` (3,)."""
    o = matvec3_of(M, v[0], v[1], v[2])
    for i in range(3):
        out[i] = o[i]


@jit
def matvec3_flat_of(m, offset, v0, v1, v2):
    """:func:`matvec3` of the (3, 3) matrix stored row major in ``m[offset : offset + 9]`` (a packed
    parameter row: no reshape, which costs a helper call per use in compiled code) and the vector
    ``(v0, v1, v2)``, as a 3-tuple; same sums.  Scalars in and out: a caller that keeps its vectors
    in rows of a scratch array makes no array view (a reference count each) to call it."""
    r0, r1, r2 = offset, offset + 3, offset + 6
    return ((m[r0] * v0 + m[r0 + 1] * v1) + m[r0 + 2] * v2, (m[r1] * v0 + m[r1 + 1] * v1) + m[r1 + 2] * v2,
            (m[r2] * v0 + m[r2 + 1] * v1) + m[r2 + 2] * v2)


@jit
def matvec3_flat(m, offset, v, out):
    """:func:`matvec3_flat_of` of the vector ``v`` (3,) into ``out`` (3,)."""
    o = matvec3_flat_of(m, offset, v[0], v[1], v[2])
    for i in range(3):
        out[i] = o[i]


@jit
def inverse3(M, out):
    """``out = M^-1`` of a non-singular (3, 3) matrix by its adjugate over its determinant.

    Written out (no LAPACK call): the bits are the same on every host, whereas
    ``numpy.linalg.inv`` goes through OpenBLAS/LAPACK kernels chosen at run time by the CPU
    (docs/parity.md).  The rounding error is of the order of ``cond(M) eps``, as LU's.  ``out``
    may not alias ``M``."""
    a, b, c = M[0, 0], M[0, 1], M[0, 2]
    d, e, f = M[1, 0], M[1, 1], M[1, 2]
    g, h, i = M[2, 0], M[2, 1], M[2, 2]
    c00 = e * i - f * h
    c01 = f * g - d * i
    c02 = d * h - e * g
    det = (a * c00 + b * c01) + c * c02
    out[0, 0] = c00 / det
    out[1, 0] = c01 / det
    out[2, 0] = c02 / det
    out[0, 1] = (c * h - b * i) / det
    out[1, 1] = (a * i - c * g) / det
    out[2, 1] = (b * g - a * h) / det
    out[0, 2] = (b * f - c * e) / det
    out[1, 2] = (c * d - a * f) / det
    out[2, 2] = (a * e - b * d) / det


@jit
def _inverse3_all(M, out):
    for n in range(M.shape[0]):
        inverse3(M[n], out[n])


def inverse3_stack(M: Any) -> np.ndarray:
    """:func:`inverse3` of a (3, 3) matrix or of each of a stack (..., 3, 3); a new float64 array
    of the same shape (e.g. ``J^-1`` of one inertia or of a campaign's per-run inertias)."""
    a = np.asarray(M, dtype=np.float64)
    if a.shape[-2:] != (3, 3):
        raise ValueError(f"inverse3_stack needs (..., 3, 3) matrices, got shape {a.shape}")
    flat = np.ascontiguousarray(a.reshape(-1, 3, 3))
    out = np.empty_like(flat)
    _inverse3_all(flat, out)
    return out.reshape(a.shape)


# ----------------------------------------------------------------------------- quaternions


@jit
def quat_multiply(p, q, out):
    """Hamilton product ``out = p ⊗ q`` (scalar last); ``out`` may alias ``p`` or ``q``."""
    p0, q0 = p[3], q[3]
    c0 = p[1] * q[2] - p[2] * q[1]
    c1 = p[2] * q[0] - p[0] * q[2]
    c2 = p[0] * q[1] - p[1] * q[0]
    w = p0 * q0 - ((p[0] * q[0] + p[1] * q[1]) + p[2] * q[2])
    x = (p0 * q[0] + q0 * p[0]) + c0
    y = (p0 * q[1] + q0 * p[1]) + c1
    z = (p0 * q[2] + q0 * p[2]) + c2
    out[0] = x
    out[1] = y
    out[2] = z
    out[3] = w


@jit
def quat_conjugate(q, out):
    """``out = (-q_v, q_0)``; ``out`` may alias ``q``."""
    out[0] = -q[0]
    out[1] = -q[1]
    out[2] = -q[2]
    out[3] = q[3]


@jit
def quat_normalize(q, out):
    """``out = q / |q|`` (non-zero ``q``), norm summed ``((x² + y²) + z²) + w²``; may alias."""
    n = np.sqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3])
    for i in range(4):
        out[i] = q[i] / n


@jit
def error_quaternion_of(q_RN, q_BN):
    """``q_BR = q_RN^* ⊗ q_BN`` with ``q_0 >= 0`` (see :func:`gnc_common.attitude.error_quaternion`),
    as a 4-tuple (x, y, z, w)."""
    # conjugate folded in: p = (-r_v, r_0)
    p0 = q_RN[3]
    px, py, pz = -q_RN[0], -q_RN[1], -q_RN[2]
    c0 = py * q_BN[2] - pz * q_BN[1]
    c1 = pz * q_BN[0] - px * q_BN[2]
    c2 = px * q_BN[1] - py * q_BN[0]
    w = p0 * q_BN[3] - ((px * q_BN[0] + py * q_BN[1]) + pz * q_BN[2])
    x = (p0 * q_BN[0] + q_BN[3] * px) + c0
    y = (p0 * q_BN[1] + q_BN[3] * py) + c1
    z = (p0 * q_BN[2] + q_BN[3] * pz) + c2
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    return x, y, z, w


@jit
def error_quaternion(q_RN, q_BN, out):
    """:func:`error_quaternion_of` into ``out`` (4,)."""
    q = error_quaternion_of(q_RN, q_BN)
    for i in range(4):
        out[i] = q[i]


@jit
def dcm_BR_times_of(x, y, z, q0, v0, v1, v2):
    """``C_e v`` with ``C_e = (q0² - q_v·q_v) I + 2 q_v q_v^T - 2 q0 q_v^x`` (eq. errorsystem), for
    ``q_BR = (x, y, z, q0)`` and ``v = (v0, v1, v2)``, as a 3-tuple."""
    qq = (x * x + y * y) + z * z
    qv_v = (x * v0 + y * v1) + z * v2
    s = q0 * q0 - qq
    two_d = 2.0 * qv_v
    two_q0 = 2.0 * q0
    c0 = y * v2 - z * v1
    c1 = z * v0 - x * v2
    c2 = x * v1 - y * v0
    return (s * v0 + two_d * x) - two_q0 * c0, (s * v1 + two_d * y) - two_q0 * c1, (s * v2 + two_d * z) - two_q0 * c2


@jit
def dcm_BR_times(q_BR, v_R, out):
    """:func:`dcm_BR_times_of` of ``q_BR`` (4,) and ``v_R`` (3,) into ``out`` (3,)."""
    o = dcm_BR_times_of(q_BR[0], q_BR[1], q_BR[2], q_BR[3], v_R[0], v_R[1], v_R[2])
    for i in range(3):
        out[i] = o[i]


@jit
def quat_rotate_of(x, y, z, w, v0, v1, v2):
    """``q ⊗ (v, 0) ⊗ q^*`` of the quaternion ``(x, y, z, w)`` and the vector ``(v0, v1, v2)``, as a
    3-tuple (the scalar core of :func:`quat_rotate`; the conjugate ``(-x, -y, -z, w)`` rotates back)."""
    # t = 2 q_v × v;  the result is v + w t + q_v × t
    t0 = 2.0 * (y * v2 - z * v1)
    t1 = 2.0 * (z * v0 - x * v2)
    t2 = 2.0 * (x * v1 - y * v0)
    return (v0 + w * t0 + (y * t2 - z * t1), v1 + w * t1 + (z * t0 - x * t2), v2 + w * t2 + (x * t1 - y * t0))


@jit
def quat_rotate(q_BN, v_B, out):
    """``out = v_N``, the components of ``v`` in N: ``q_BN ⊗ (v_B, 0) ⊗ q_BN^*``."""
    o = quat_rotate_of(q_BN[0], q_BN[1], q_BN[2], q_BN[3], v_B[0], v_B[1], v_B[2])
    out[0] = o[0]
    out[1] = o[1]
    out[2] = o[2]


@jit(inline="always")  # inlined: the SIMD lanes' loops vectorise only with no call left in them
def gamma_inverse_of(q1, q2, q3, q0_raw, x0, x1, x2, q0_floor):
    """``Gamma(q_e)^-1 x = 2 (q0 x - q_v × x + q_v (q_v·x) / q0)`` for ``q_e = (q1, q2, q3, q0_raw)``
    and ``x = (x0, x1, x2)``, ``q0`` floored at ``q0_floor`` (docs/paper_notes.md, error 5): finite
    and bounded by ``2 (1 + 1/q0_floor) |x|`` at 180 deg; a 3-tuple.  Closed form of
    ``(q0 I + q_v^x)^-1 = q0 I - q_v^x + q_v q_v^T / q0`` for a unit quaternion."""
    q0 = max(q0_raw, q0_floor)
    d = ((q1 * x0 + q2 * x1) + q3 * x2) / q0
    c0 = q2 * x2 - q3 * x1
    c1 = q3 * x0 - q1 * x2
    c2 = q1 * x1 - q2 * x0
    return 2.0 * ((q0 * x0 - c0) + d * q1), 2.0 * ((q0 * x1 - c1) + d * q2), 2.0 * ((q0 * x2 - c2) + d * q3)


@jit
def gamma_inverse_times(q_BR, x, q0_floor, out):
    """:func:`gamma_inverse_of` of ``q_BR`` (4,) and ``x`` (3,) into ``out`` (3,)."""
    o = gamma_inverse_of(q_BR[0], q_BR[1], q_BR[2], q_BR[3], x[0], x[1], x[2], q0_floor)
    for i in range(3):
        out[i] = o[i]

