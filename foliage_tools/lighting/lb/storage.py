"""Storage formats of the lattice densities: float32, or scaled IEEE half precision with float32 arithmetic.

The model is FluidX3D's FP16 storage (Lehmann et al. 2022, "Accuracy and performance of the
lattice Boltzmann method with 64-bit, 32-bit, and customized 16-bit number formats", Phys. Rev.
E 106, 015308): the densities are *stored* in 16 bits and every sweep widens them to float32,
collides and streams in float32, and rounds the result back to 16 bits once, when it is stored.
The sweep is memory-bound, so halving the bytes per density nearly halves its traffic, and one
rounding per stored value per sweep is all the precision the format costs.

Which 16-bit format
-------------------
Lehmann et al. shift the exponent range of their formats so it covers the values LBM densities
take (FP16S: IEEE half with the densities' equilibrium offset removed and a power-of-two scale).
Light densities here have no offset (they are >= 0 and fall to 0 in deep shade), so the format
is IEEE binary16 (5 exponent bits, 10 mantissa bits: relative rounding error <= 2^-11 = 4.9e-4
for normal numbers) of ``f * 2^FP16_SCALE_EXP``: multiplying by a power of two is exact, so this
only moves binary16's window of normal numbers, [2^-14, 65504], to [2^-14-S, 65504 * 2^-S] in f
(the bias of a custom exponent, as FP16S has, at the price of one multiply). With S = 8 (below),
f is stored with full 11-bit precision from 2^-22 = 2.4e-7 up to 255.9, and below that as
subnormals (absolute error <= 2^-33 = 1.2e-10). Why these bounds:

* top: boundary inflow is 1 and a density never exceeds the largest inflow by much (the
  update's column sums are <= 1, ``lb`` "Stability policy"), but an extrapolation jump
  (``lb._MAX_EXTRAPOLATION_Q``) may move a value up to 199x its last change before the
  residual test catches it; 255 leaves that room, and overflow to inf is caught by the
  solver's finite check (``LBNumericalError``) rather than passed on.
* bottom: the value an error of 2^-33 per density spoils is far below anything a leaf sees
  (``benchmarks/bench_lb_storage.py`` prints the smallest per-leaf E_scattered of the example tree
  and the fraction of stored densities that fall below 2^-22).

bfloat16 (8 exponent bits, 7 mantissa bits: 2^-8 = 0.39 % per rounding) was not used: one
rounding alone would eat most of the issue's 0.5 % error budget.

The conversion is the hardware's (``fptrunc`` / ``fpext`` between float and half in LLVM: one
F16C ``vcvtps2ph`` / ``vcvtph2ps`` per 8 or 16 values, round to nearest even), emitted through a
numba intrinsic: numba 0.68 has no float16 arrays on the CPU (``NotImplementedError: float16``),
so a half is held in a uint16 array and bitcast.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic, overload

__all__ = ["STORAGES", "FP16_SCALE_EXP", "storage_dtype", "to_storage", "from_storage", "load", "convert", "HALF_ROUNDING_VARIANCE"]

#: ``--storage`` choices: what the lattice densities are stored in (arithmetic is float32 either way).
STORAGES = ("fp32", "fp16")

#: S in f * 2^S, the value held in binary16 (module docstring: normal range 2.4e-7 .. 255.9 in f).
FP16_SCALE_EXP = 8
_UP = np.float32(2.0**FP16_SCALE_EXP)
_DOWN = np.float32(2.0**-FP16_SCALE_EXP)

#: Variance of the error of rounding a value to the nearest stored binary16 one, in f's units, indexed by the
#: binary16 exponent field (bits >> 10 & 31) of the stored value: ulp^2 / 12 with ulp = 2^(max(e, 1) - 25 - S)
#: (10 fraction bits; e = 0 is subnormal, with the ulp of e = 1), the variance of a uniform error over one ulp
#: (the standard model of round-to-nearest; ``lighting.lb.solvers`` uses it to tell when an fp16 solve's change
#: per sweep is no more than its rounding). Entry 31 (inf and NaN) is never reached by a finite field.
HALF_ROUNDING_VARIANCE = np.array([(2.0 ** (max(e, 1) - 25 - FP16_SCALE_EXP)) ** 2 / 12.0 for e in range(32)])


def storage_dtype(storage: str, compute_dtype="float32") -> np.dtype:
    """The numpy dtype of a stored field: the compute dtype for ``fp32``, uint16 (binary16 bits) for ``fp16``."""
    if storage not in STORAGES:
        raise ValueError(f"storage must be one of {', '.join(STORAGES)}, got {storage!r}")
    return np.dtype(np.uint16) if storage == "fp16" else np.dtype(compute_dtype)


def to_storage(values, dtype) -> np.ndarray:
    """Values (any float array) in storage ``dtype``: binary16 bits of values * 2^S for uint16 (numpy rounds to nearest even, as ``fptrunc``)."""
    dtype = np.dtype(dtype)
    if dtype == np.uint16:
        return (np.asarray(values, np.float32) * _UP).astype(np.float16).view(np.uint16)
    return np.asarray(values, dtype)


def from_storage(stored: np.ndarray, compute_dtype="float32") -> np.ndarray:
    """The values a stored array holds, in ``compute_dtype`` (the inverse of ``to_storage``, exact)."""
    if stored.dtype == np.uint16:
        return stored.view(np.float16).astype(np.float32) * _DOWN
    return np.asarray(stored, compute_dtype)


# --------------------------------------------------------------------------- in numba kernels


@intrinsic
def _half_bits_to_f32(typingctx, bits):
    """float32 of the binary16 number whose bits are ``bits`` (uint16): LLVM ``fpext half -> float`` (exact)."""
    if not (isinstance(bits, types.Integer) and bits.bitwidth == 16):
        return None
    sig = types.float32(bits)

    def codegen(context, builder, signature, args):
        return builder.fpext(builder.bitcast(args[0], ir.HalfType()), ir.FloatType())

    return sig, codegen


@intrinsic
def _f32_to_half_bits(typingctx, value):
    """Bits (uint16) of ``value`` (float32) rounded to binary16, nearest even: LLVM ``fptrunc float -> half``."""
    if value != types.float32:
        return None
    sig = types.uint16(value)

    def codegen(context, builder, signature, args):
        return builder.bitcast(builder.fptrunc(args[0], ir.HalfType()), ir.IntType(16))

    return sig, codegen


def load(x):  # pragma: no cover - replaced by the overload inside numba
    """The value of one stored density (in numba kernels): float32 from binary16 bits, else the value itself."""
    raise NotImplementedError("storage.load is for numba kernels")


def convert(value, like):  # pragma: no cover - replaced by the overload inside numba
    """``value`` as it is stored in array ``like`` (in numba kernels): binary16 bits for uint16, else the value."""
    raise NotImplementedError("storage.convert is for numba kernels")


@overload(load, inline="always")
def _load_impl(x):
    if isinstance(x, types.Integer) and x.bitwidth == 16:
        down = _DOWN

        def widen(x):
            return _half_bits_to_f32(x) * down

        return widen
    return lambda x: x


@overload(convert, inline="always")
def _convert_impl(value, like):
    if isinstance(like, types.Array) and like.dtype == types.uint16:
        up = _UP

        def narrow(value, like):
            return _f32_to_half_bits(np.float32(value) * up)

        return narrow
    return lambda value, like: value
