"""The laws' five libm functions, called as scalars and, in a loop over SIMD lanes, as glibc's libmvec.

``exp``, ``pow``, ``atan``, ``tanh`` and ``expm1`` here are compiled calls of glibc's scalar
functions whose LLVM declaration, in the functions of :data:`VECTOR_MODULES` (the SIMD lanes)
only, also names their vector variants in glibc's libmvec (the vector function ABI's
``"vector-function-abi-variant"`` attribute: what ``#pragma omp declare simd`` declares in C), and
says everywhere that they touch no memory (``memory(none)``: no errno, what
``-fno-math-errno`` declares).  Outside a vectorised loop nothing changes: the call is the
scalar glibc function numba calls for ``np.exp`` and the others (the same function, the same
bits).  Inside a loop that LLVM's loop vectorizer widens (the lane kernel of
:mod:`sappc.offline.lanes`), each call becomes one call of the libmvec variant of the loop's
width, which is what makes the lane kernel's libm 4 to 9 times cheaper per element
(docs/performance.md, "SIMD lanes").  libmvec's results are within 3 ulps of the scalar
functions' (measured: docs/parity.md, "Campaign runs in SIMD lanes"), and may differ between its
widths: a run computed in lanes is reproducible bit for bit by the same lane kernel on the same
host, not by the scalar path.

Why not numba's own routes: PyPI's llvmlite is not patched for Intel's SVML, and LLVM's
``-vector-library`` option does not reach numba's pass builder (both measured:
docs/performance.md, "Vectorised libm with this llvmlite").

The variants declared are, for each vector width, the best one the compile target's CPU features
allow (width 2: SSE2 ``b``; width 4: ``d`` with AVX2, else ``c`` with AVX; width 8: ``e`` with
AVX-512F): LLVM picks a variant by its width only, the first of that width it is given;
none when glibc's libmvec cannot be loaded (then a vectorised loop calls the scalar function per
lane, the same bits as the scalar path).  libmvec is loaded into the process (:func:`install`,
called by :func:`gnc_common.compiled.numba_module` before any kernel is compiled or loaded from
the cache: cached machine code names the variants).  numba's cache keys on the CPU itself;
``SAPPC_LIBMVEC=0`` (declare no variant) is part of the cache directory's name
(:func:`gnc_common.compiled.kernel_sources_digest`)."""

from __future__ import annotations

import os
from typing import Any

from gnc_common.compiled import LIBMVEC_ENV, jit

__all__ = ["LIBMVEC", "VECTOR_MODULES", "atan", "exp", "expm1", "install", "installed_variants", "pow", "tanh"]

#: glibc's vector math library (glibc >= 2.22 on x86-64).
LIBMVEC = "libmvec.so.1"
#: The functions and their number of arguments.
_FUNCTIONS = {"exp": 1, "pow": 2, "atan": 1, "tanh": 1, "expm1": 1}
#: The vector function ABI's x86 ISA letters, the CPU feature each needs (None: the x86-64
#: baseline, SSE2) and the width of a float64 vector (2 in xmm, 4 in ymm, 8 in zmm).
_ISAS = (("b", None, 2), ("c", "avx", 4), ("d", "avx2", 4), ("e", "avx512f", 8))

#: The modules whose compiled functions call the variants (their functions' mangled names start
#: so): the SIMD lanes.  Everywhere else the calls are declared scalar only, so that LLVM's SLP
#: vectorizer cannot pair two calls of the scalar path (the nodes, ``sappc simulate``, the
#: per-run loop) into a libmvec call: the scalar path keeps the scalar functions' bits.
VECTOR_MODULES = ("sappc.offline.lanes",)
_VECTOR_FUNCTIONS = tuple("_ZN" + "".join(f"{len(part)}{part}" for part in m.split(".")) for m in VECTOR_MODULES)

_variants: tuple[tuple[str, int], ...] | None = None  # (isa, width) of each declared variant; None until install()
_intrinsics: dict[str, Any] = {}


def _target_features() -> set[str] | None:
    """The CPU features numba compiles for (``NUMBA_CPU_NAME``/``NUMBA_CPU_FEATURES``, else the
    host's), or None where they cannot be told (then only the baseline's variant is declared)."""
    name = os.environ.get("NUMBA_CPU_NAME")
    features = os.environ.get("NUMBA_CPU_FEATURES")
    if features is None and name not in (None, "", "host"):
        return None  # a named CPU without features: numba compiles for its baseline
    if features is None:
        import llvmlite.binding as llvm

        try:
            features = llvm.get_host_cpu_features().flatten()
        except RuntimeError:
            return None
    return {f[1:] for f in features.split(",") if f.startswith("+")}


def _choose_variants() -> tuple[tuple[str, int], ...]:
    """The variants to declare: none without libmvec (or with ``SAPPC_LIBMVEC=0``), else those
    the target's features allow."""
    if os.environ.get(LIBMVEC_ENV, "1") == "0":
        return ()
    import llvmlite.binding as llvm

    try:
        llvm.load_library_permanently(LIBMVEC)  # dlopen's search: glibc's own library directory
    except RuntimeError:
        return ()
    features = _target_features()
    best: dict[int, str] = {}  # one variant per width, the best ISA the target has (LLVM takes the first of a width)
    for isa, need, width in _ISAS:
        if need is None or (features is not None and need in features):
            best[width] = isa
    return tuple((isa, width) for width, isa in sorted(best.items()))


def installed_variants() -> tuple[tuple[str, int], ...]:
    """The (ISA letter, width) of the variants this process declares (:func:`install` first)."""
    if _variants is None:
        raise RuntimeError("gnc_common.libm.install() has not run: no kernel was compiled or loaded yet")
    return _variants


def _intrinsic(name: str, nargs: int, variants: tuple[tuple[str, int], ...]) -> Any:
    """A numba intrinsic calling glibc's scalar ``name``, declared with its libmvec ``variants``
    (module docstring); the variants are declared in the module and kept (``llvm.compiler.used``)
    so that the vectorizer finds them."""
    from llvmlite import ir
    from numba.core import cgutils, types
    from numba.extending import intrinsic

    d = ir.DoubleType()
    names = [f"_ZGV{isa}N{w}{'v' * nargs}_{name}" for isa, w in variants]

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:  # noqa: ARG001
        mod = builder.module
        vector = bool(names) and builder.function.name.startswith(_VECTOR_FUNCTIONS)
        fn = cgutils.get_or_insert_function(mod, ir.FunctionType(d, [d] * nargs), name)
        attrs = ["nounwind", "readnone"]
        if vector:
            attrs.append('"vector-function-abi-variant"="' + ",".join(f"{m}({m})" for m in names) + '"')
        for a in attrs:
            set.add(fn.attributes, a)  # llvmlite's attribute set accepts only its known names: the string one added as is
        used = [cgutils.get_or_insert_function(mod, ir.FunctionType(ir.VectorType(d, w), [ir.VectorType(d, w)] * nargs), m)
                for (_, w), m in zip(variants, names)] if vector else []
        if used:  # every function's variants kept: a declaration nothing uses is dropped before the vectorizer looks for it
            pt = ir.PointerType(ir.IntType(8))
            kept = mod.__dict__.setdefault("_sappc_libmvec_kept", {})  # name -> declaration, this module's
            for u in used:
                kept.setdefault(u.name, u)
            arr = ir.ArrayType(pt, len(kept))
            g = mod.globals.get("llvm.compiler.used")
            if g is None:
                g = ir.GlobalVariable(mod, arr, "llvm.compiler.used")
                g.linkage = "appending"
                g.section = "llvm.metadata"
            g.value_type = arr  # the module's one list, grown in place
            g.initializer = ir.Constant(arr, [u.bitcast(pt) for u in kept.values()])
        return builder.call(fn, args)

    if nargs == 1:
        def typer1(typingctx: Any, x: Any) -> Any:  # noqa: ARG001
            return types.float64(types.float64), codegen
        typer1.__name__ = f"libm_{name}"
        return intrinsic(typer1)

    def typer2(typingctx: Any, x: Any, y: Any) -> Any:  # noqa: ARG001
        return types.float64(types.float64, types.float64), codegen
    typer2.__name__ = f"libm_{name}"
    return intrinsic(typer2)


def install() -> None:
    """Load libmvec and make the intrinsics (once per process; numba imported)."""
    global _variants
    if _variants is not None:
        return
    variants = _choose_variants()
    for name, nargs in _FUNCTIONS.items():
        _intrinsics[name] = _intrinsic(name, nargs, tuple((isa, w) for isa, w in variants))
    globals().update({f"_{name}": f for name, f in _intrinsics.items()})
    _variants = variants


_exp: Any = None  # the intrinsics, set by install()
_pow: Any = None
_atan: Any = None
_tanh: Any = None
_expm1: Any = None


@jit(inline="always")
def exp(x):  # a numba kernel
    """``e**x`` (glibc's ``exp``)."""
    return _exp(x)


@jit(inline="always")
def pow(x, y):  # noqa: A001 (libm's name)  # a numba kernel
    """``x**y`` (glibc's ``pow``)."""
    return _pow(x, y)


@jit(inline="always")
def atan(x):  # a numba kernel
    """``arctan x`` (glibc's ``atan``)."""
    return _atan(x)


@jit(inline="always")
def tanh(x):  # a numba kernel
    """``tanh x`` (glibc's ``tanh``)."""
    return _tanh(x)


@jit(inline="always")
def expm1(x):  # a numba kernel
    """``e**x - 1`` (glibc's ``expm1``)."""
    return _expm1(x)
