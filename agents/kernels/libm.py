"""Scalar maths that must give CPython's bits inside kernels.

CPython computes ``x ** y`` on floats with the C library's ``pow``. LLVM rewrites a call ``pow(x, 2.0)``
with a constant exponent into ``x * x``, which differs from glibc's ``pow`` in the last bit on ~0.08 % of
inputs (measured: 253 of 300,000 draws). :func:`pow_libm` keeps the library call: its declaration carries
LLVM's ``nobuiltin`` attribute, so the optimiser does not treat it as the builtin it knows how to fold.
Interpreted (``py_func``, ``NUMBA_DISABLE_JIT=1``) it is Python's own ``**`` (which raises OverflowError
where the compiled call returns inf).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload


def pow_libm(x: float, y: float) -> float:
    """``x ** y`` for floats, as CPython computes it (libm ``pow``), also inside kernels."""
    return x**y


@intrinsic
def _pow_call(typingctx, x, y):  # type: ignore[no-untyped-def]
    sig = types.float64(types.float64, types.float64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        fnty = ir.FunctionType(ir.DoubleType(), [ir.DoubleType(), ir.DoubleType()])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "pow")
        fn.attributes.add("nobuiltin")
        return builder.call(fn, args)

    return sig, codegen


@overload(pow_libm)
def _pow_libm_impl(x, y):  # type: ignore[no-untyped-def]
    if isinstance(x, types.Float) and isinstance(y, types.Float):
        return lambda x, y: _pow_call(x, y)
    return None
