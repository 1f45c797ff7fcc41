"""Calls between compiled code through C function pointers: the one way a compiled loop that is
compiled once (the small-problem solver, :mod:`lie_factors.batch.small`) reaches kernels that are
generated later (a factor kind's, a group's retraction).

A kernel reached this way is a numba ``cfunc`` of one signature, ``int64 f(int64* d)``: ``d`` is
its *descriptor*, an int64 array holding the addresses and leading dimensions of the arrays it
works on and its scalar arguments, at positions its generator fixed
(:func:`lie_factors.expressions.codegen.c_entry_source`).  Inside it, :func:`f64_array_at`-style
views (``numba.carray(f64_at(d[i]), shape)``) turn an address back into an array; the caller
:func:`call_c`\\ s it by address.  An indirect call costs a few nanoseconds, and neither side
is compiled again when the other changes: the caller's compiled code holds no callee.

The arrays a descriptor points at must outlive every call through it: their owner (the Python
object that wrote the descriptor) keeps them.
"""

from __future__ import annotations

from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

__all__ = ["C_SIGNATURE", "f64_at", "i64_at", "call_c"]

#: The one signature of a kernel called by address: ``int64 f(int64* descriptor)``.
C_SIGNATURE = types.int64(types.CPointer(types.int64))


@intrinsic
def f64_at(typingctx, address):
    """The float64 pointer at the integer ``address`` (for ``numba.carray``)."""

    def codegen(context, builder, sig, args):
        return builder.inttoptr(args[0], ir.DoubleType().as_pointer())

    return types.CPointer(types.float64)(address), codegen


@intrinsic
def i64_at(typingctx, address):
    """The int64 pointer at the integer ``address`` (for ``numba.carray``)."""

    def codegen(context, builder, sig, args):
        return builder.inttoptr(args[0], ir.IntType(64).as_pointer())

    return types.CPointer(types.int64)(address), codegen


@intrinsic
def call_c(typingctx, address, descriptor):
    """``f(descriptor)`` for the ``int64 f(int64*)`` kernel at the integer ``address``;
    ``descriptor``: an int64 array's ``.ctypes`` (numba passes its data pointer).  Returns f's
    int64."""

    def codegen(context, builder, sig, args):
        i64 = ir.IntType(64)
        fn = builder.inttoptr(args[0], ir.FunctionType(i64, [i64.as_pointer()]).as_pointer())
        return builder.call(fn, [args[1]])

    return types.int64(types.int64, types.CPointer(types.int64)), codegen
