"""Compiled array work: the ``jit`` every mechanism's per-step loop uses (spec/simulator.md,
"Speed").

At the paper's 40 robots a numpy operation costs far more in its call than in its arithmetic,
and a step needed about sixty of them; at 4,000 robots the pairs of nearby robots dominate. So
each mechanism's step is one loop over the robots, compiled by numba on first use and cached on
disk, so that a study's worker processes load the compiled code instead of compiling it again.
The cache is ``NUMBA_CACHE_DIR`` if set, else ``ktbt/numba`` in the user's cache folder
(``XDG_CACHE_HOME`` or ``~/.cache``). A call's cost is mostly its arguments' (typing and
unboxing each): the kernels take arrays and numbers, and the trial's random generator as the
addresses of its bit generator (:func:`generator_pointers`, :func:`generator`).
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numpy as np

os.environ.setdefault(
    "NUMBA_CACHE_DIR",
    str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ktbt" / "numba"),
)

try:
    import numba
    from numba.core import cgutils as _cgutils
    from numba.core import types
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover - the sim extra installs it
    raise ImportError("the simulator needs the sim extra: pip install 'ktbt[sim]'") from None

F = TypeVar("F", bound=Callable[..., object])
cgutils: Any = _cgutils  # numba's code generation helpers are untyped


def jit(function: F) -> F:
    """Compile ``function`` in nopython mode, cached on disk."""
    return cast(F, numba.njit(cache=True, nogil=True)(function))


def generator_pointers(rng: np.random.Generator) -> np.ndarray:
    """The addresses a compiled kernel needs to draw from ``rng``'s bit generator: its state
    and its three ``next_*`` functions, as numba's own unboxing of a ``Generator`` reads them.

    Passing a ``Generator`` to a compiled function costs about 10 µs a call (typing it and
    unboxing it through ctypes each time); these addresses are read once per trial and
    :func:`generator` rebuilds the same generator inside the kernel, so the draws are numba's
    own, bit for bit. The addresses stay valid as long as ``rng`` lives."""
    binding = rng.bit_generator.ctypes
    address = [
        binding.state_address,
        binding.state.value,
        *(
            ctypes.cast(f, ctypes.c_void_p).value
            for f in (binding.next_uint64, binding.next_uint32, binding.next_double)
        ),
        binding.bit_generator.value,
    ]
    return np.array(address, dtype=np.uint64)


_GENERATOR = types.NumPyRandomGeneratorType("NumPyRandomGeneratorType")
_BIT_GENERATOR = types.NumPyRandomBitGeneratorType("bit_generator")
_FIELDS = (
    "state_address",
    "state",
    "fnptr_next_uint64",
    "fnptr_next_uint32",
    "fnptr_next_double",
    "bit_generator",
)


def _generator(typingctx: object, pointers: types.Array) -> tuple[object, Callable[..., object]]:
    """Inside a kernel: the ``np.random.Generator`` whose :func:`generator_pointers` are
    ``pointers`` (a uint64 array), with no Python object behind it (nothing is boxed back)."""

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        array = context.make_array(signature.args[0])(context, builder, args[0])
        bits = cgutils.create_struct_proxy(_BIT_GENERATOR)(context, builder)
        bits.parent = cgutils.get_null_value(bits.parent.type)
        for k, field in enumerate(_FIELDS):
            value = builder.load(cgutils.gep_inbounds(builder, array.data, k))
            setattr(bits, field, value)
        out = cgutils.create_struct_proxy(_GENERATOR)(context, builder)
        out.bit_generator = bits._getvalue()
        out.meminfo = cgutils.get_null_value(out.meminfo.type)
        out.parent = cgutils.get_null_value(out.parent.type)
        return out._getvalue()

    return _GENERATOR(pointers), codegen


generator = cast(Callable[[np.ndarray], Any], intrinsic(_generator))
