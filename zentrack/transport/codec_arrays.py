"""Arrays on the wire: packing numpy arrays into message fields, and unpacking them with every check a
receiver needs (shape, finiteness, range, symmetry, positive (semi)definiteness).

Arrays travel as raw little-endian float64 bytes with their shape (``{"shape": [...], "data": b"..."}``);
symmetric matrices as the packed upper triangle (``{"sym": n, "data": b"..."}``, n(n+1)/2 values, row by row).

The checks are the tracker's per-message cost, so small arrays take fast paths (``tests/test_fast_paths.py``
pins them against the numpy versions they replaced): arrays of at most :data:`LOOP_MAX_VALUES` values are
checked by plain loops over the unpacked floats, and positive definiteness by LAPACK's ``potrf`` called
directly. Callers import these names from :mod:`zentrack.transport.codec`, which re-exports them.
"""
from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from zentrack.transport.codec_types import MAX_COORDINATE, MAX_DIM, MAX_RETURNS, WireError, short

# ---------------------------------------------------------------- packing

def pack_array(a: np.ndarray) -> dict:
    a = np.ascontiguousarray(a, dtype="<f8")
    return {"shape": list(a.shape), "data": a.tobytes()}


_TRIU: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _triu(n: int) -> tuple[np.ndarray, np.ndarray]:
    if n not in _TRIU:
        _TRIU[n] = np.triu_indices(n)
    return _TRIU[n]


def pack_symmetric(m: np.ndarray) -> dict:
    n = m.shape[-1]
    iu = _triu(n)
    return {"sym": n, "data": np.ascontiguousarray(m[iu], dtype="<f8").tobytes()}


def pack_blocks(blocks: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict:
    return {name: {"Y": pack_symmetric(mat), "y": pack_array(vec)} for name, (mat, vec) in blocks.items()}


# ---------------------------------------------------------------- arrays

#: arrays of at most this many values are checked by a plain loop over the unpacked floats (no numpy call
#: overhead); larger ones by numpy
LOOP_MAX_VALUES = 16
_STRUCTS: dict[int, struct.Struct] = {}
#: per n: for each entry of an n x n matrix, its index in the packed upper triangle (an n x n array)
_SYM_GATHER: dict[int, np.ndarray] = {}


def _finite_values(data: bytes, count: int, name: str, bound: float | None = None) -> np.ndarray:
    """The ``count`` little-endian float64 values of ``data`` (``8 * count`` bytes, checked by the caller) as a
    new writable array; WireError('nonfinite') if one is NaN or infinite, then WireError('range') if one's
    magnitude passes ``bound``."""
    if count <= LOOP_MAX_VALUES:
        unpacker = _STRUCTS.get(count)
        if unpacker is None:
            unpacker = _STRUCTS[count] = struct.Struct(f"<{count}d")
        values = unpacker.unpack(data)
        if not all(map(math.isfinite, values)):
            raise WireError("nonfinite", f"{name}: NaN or Inf")
        if bound is not None and count and (max(values) > bound or min(values) < -bound):
            raise WireError("range", f"{name}: a value of magnitude {max(map(abs, values)):.3g} > {bound:g}")
        return np.array(values, dtype=float)
    raw = np.frombuffer(data, dtype="<f8")
    if not np.isfinite(raw).all():
        raise WireError("nonfinite", f"{name}: NaN or Inf")
    return within_range(raw.astype(float), name, bound) if bound is not None else raw.astype(float)


def _sym_gather(n: int) -> np.ndarray:
    if n not in _SYM_GATHER:
        pos = np.empty((n, n), dtype=np.intp)
        iu = _triu(n)
        pos[iu] = np.arange(iu[0].size)
        pos[(iu[1], iu[0])] = pos[iu]
        _SYM_GATHER[n] = pos
    return _SYM_GATHER[n]


def _array_data(obj: Any, shape: tuple[int, ...], name: str) -> bytes:
    """The data bytes of an array field of exactly ``shape`` (its form checked; its values not)."""
    if type(obj) is not dict or type(obj.get("data")) is not bytes or type(obj.get("shape")) is not list:
        raise WireError("schema", f"{name}: expected {{shape, data}}")
    if tuple(obj["shape"]) != shape:
        raise WireError("shape", f"{name}: shape {obj['shape']} != expected {list(shape)}")
    if len(obj["data"]) != 8 * math.prod(shape):
        raise WireError("shape", f"{name}: {len(obj['data'])} bytes do not match shape {list(shape)}")
    return obj["data"]


def _packed_data(obj: dict, n: int, name: str) -> bytes:
    """The data bytes of a packed symmetric matrix field (``{"sym": n, "data": ...}``; its form checked)."""
    if obj.get("sym") != n or type(obj.get("data")) is not bytes:
        raise WireError("shape", f"{name}: packed size {short(obj.get('sym'))} != expected {n}")
    if len(obj["data"]) != 8 * n * (n + 1) // 2:
        raise WireError("shape", f"{name}: {len(obj['data'])} bytes do not hold a packed {n}x{n} matrix")
    return obj["data"]


def unpack_array(obj: Any, shape: tuple[int, ...], name: str, bound: float | None = None) -> np.ndarray:
    """An array of exactly ``shape``, every value finite (and within ``bound``, reason ``range``)."""
    values = _finite_values(_array_data(obj, shape, name), math.prod(shape), name, bound)
    return values if len(shape) == 1 else values.reshape(shape)


def unpack_symmetric(obj: Any, n: int, name: str) -> np.ndarray:
    """A symmetric matrix from the packed upper triangle (or a full matrix, then checked for symmetry)."""
    if type(obj) is dict and "sym" in obj:
        data, count = _packed_data(obj, n, name), n * (n + 1) // 2
        if count > LOOP_MAX_VALUES:  # the gather below copies: no need for _finite_values' copy
            tri = np.frombuffer(data, dtype="<f8")
            if not np.isfinite(tri).all():
                raise WireError("nonfinite", f"{name}: NaN or Inf")
            return tri[_sym_gather(n)].astype(float, copy=False)
        return _finite_values(data, count, name)[_sym_gather(n)]
    m = unpack_array(obj, (n, n), name)
    with np.errstate(over="ignore"):  # m - m.T of values near 1e308 is inf: not symmetric
        if not np.allclose(m, m.T, rtol=1e-12, atol=0.0):
            raise WireError("asymmetric", f"{name}: not symmetric")
    return 0.5 * m + 0.5 * m.T  # 0.5 * (m + m.T), the same bits, without overflowing near 1e308


def unpack_vectors(objs: Sequence[Any], n: int, name_of: Callable[[int], str], bound: float | None = None) -> np.ndarray:
    """:func:`unpack_array` ``(obj, (n,), name_of(i), bound)`` of every ``objs[i]`` as one ``(len(objs), n)`` array:
    each one's form checked in turn, the values of all at once (a list of many tracks: one numpy check, not one per
    track); the first failing one named, by the same reasons."""
    def data(i: int, obj: Any) -> bytes:  # (the name made only for a field that fails)
        if (type(obj) is dict and type(obj.get("data")) is bytes and obj.get("shape") == [n]
                and len(obj["data"]) == 8 * n):
            return obj["data"]
        return _array_data(obj, (n,), name_of(i))

    rows = _rows(b"".join([data(i, obj) for i, obj in enumerate(objs)]), len(objs), n, name_of)
    if bound is not None and rows.size:
        largest = np.abs(rows).max(axis=1)
        if (largest > bound).any():
            i = int(np.flatnonzero(largest > bound)[0])
            raise WireError("range", f"{name_of(i)}: a value of magnitude {largest[i]:.3g} > {bound:g}")
    return rows.astype(float)


def unpack_symmetrics(objs: Sequence[Any], n: int, name_of: Callable[[int], str]) -> np.ndarray:
    """:func:`unpack_symmetric` ``(obj, n, name_of(i))`` of every ``objs[i]`` as one ``(len(objs), n, n)`` array:
    packed upper triangles checked all at once as :func:`unpack_vectors` does; a list with a full matrix in it
    one by one."""
    if not all(type(obj) is dict and "sym" in obj for obj in objs):
        return np.stack([unpack_symmetric(obj, n, name_of(i)) for i, obj in enumerate(objs)]).reshape(-1, n, n)
    count = n * (n + 1) // 2

    def data(i: int, obj: dict) -> bytes:  # (the name made only for a field that fails)
        if obj.get("sym") == n and type(obj.get("data")) is bytes and len(obj["data"]) == 8 * count:
            return obj["data"]
        return _packed_data(obj, n, name_of(i))

    tri = _rows(b"".join([data(i, obj) for i, obj in enumerate(objs)]), len(objs), count, name_of)
    return tri[:, _sym_gather(n)].astype(float, copy=False)


def _rows(data: bytes, count: int, width: int, name_of: Callable[[int], str]) -> np.ndarray:
    """``count`` rows of ``width`` little-endian float64 values (read-only), WireError('nonfinite') naming the first
    row with a NaN or an infinity."""
    rows = np.frombuffer(data, dtype="<f8").reshape(count, width)
    finite = np.isfinite(rows).all(axis=1)
    if not finite.all():
        raise WireError("nonfinite", f"{name_of(int(np.flatnonzero(~finite)[0]))}: NaN or Inf")
    return rows


def leading_dim(obj: Any, ndim: int, cap: int, name: str) -> int:
    """The first dimension of an array of ``ndim`` dimensions: an int from 0 to ``cap`` (its other
    dimensions and its data are checked by :func:`unpack_array`)."""
    shape = obj.get("shape") if type(obj) is dict else None
    if type(shape) is not list or len(shape) != ndim:
        raise WireError("schema", f"{name}: expected {'a vector' if ndim == 1 else f'an array of {ndim} dimensions'}")
    rows = shape[0]
    if type(rows) is not int or not 0 <= rows <= cap:
        raise WireError("shape", f"{name}: {short(rows)} rows, expected 0 to {cap}")
    return rows


def unpack_vector(obj: Any, name: str) -> np.ndarray:
    """A state vector of unknown dimension n, 1 <= n <= MAX_DIM."""
    n = leading_dim(obj, 1, MAX_DIM, name)
    if n == 0:
        raise WireError("shape", f"{name}: an empty state")
    return unpack_array(obj, (n,), name)


def optional_rows(obj: Any, width: int | None, cap: int, name: str) -> np.ndarray | None:
    """An optional ``(S, width)`` array (``(S,)`` when ``width`` is None) with S <= ``cap``; None if absent."""
    if obj is None:
        return None
    rows = leading_dim(obj, 1 if width is None else 2, cap, name)
    return unpack_array(obj, (rows,) if width is None else (rows, width), name)


def unpack_returns(obj: Any, m: int) -> np.ndarray:
    """A scan's returns ``(J, m)``, 0 <= J <= MAX_RETURNS, each value within MAX_COORDINATE."""
    j = leading_dim(obj, 2, MAX_RETURNS, "returns")
    return unpack_array(obj, (j, m), "returns", MAX_COORDINATE)


def unpack_pose(obj: Any) -> np.ndarray:
    """A sensor position ``(3,)`` within MAX_COORDINATE."""
    return unpack_array(obj, (3,), "pose", MAX_COORDINATE)


def all_within(arr: np.ndarray, lo: float, hi: float) -> bool:
    """Whether every value of ``arr`` (finite) lies in ``[lo, hi]`` (a plain loop on a few values: ``np.all``
    on a small array costs a microsecond)."""
    if arr.size > LOOP_MAX_VALUES:
        return bool(arr.min() >= lo and arr.max() <= hi)
    values = arr.ravel().tolist()
    return not values or (min(values) >= lo and max(values) <= hi)


def within_range(arr: np.ndarray, what: str, bound: float = MAX_COORDINATE) -> np.ndarray:
    """``arr`` itself if no value's magnitude passes ``bound`` (reason ``range`` otherwise)."""
    if not arr.size:
        return arr
    # a plain loop on a few values (a bearing, a pose) is cheaper than numpy's per-call overhead
    largest = max(map(abs, arr.ravel().tolist())) if arr.size <= LOOP_MAX_VALUES else float(np.max(np.abs(arr)))
    if largest > bound:
        raise WireError("range", f"{what}: a value of magnitude {largest:.3g} > {bound:g}")
    return arr


# ---------------------------------------------------------------- matrices

def check_pd(m: np.ndarray, name: str) -> None:
    """WireError('not_pd') unless the Cholesky factorisation of ``m`` (finite, symmetric) succeeds
    (:func:`~zentrack.fusion.linalg.cholesky_one`: numpy's LAPACK ``potrf`` without its Python wrapper, so a
    tracker maps no SciPy library)."""
    from zentrack.fusion.linalg import cholesky_one  # (on first use: ``zentrack health`` loads no fusion module)

    if cholesky_one(m) is None:
        raise WireError("not_pd", f"{name}: not positive definite")


#: blocks that carry an information *increment* (paper 4 consensus on measurements): positive semidefinite,
#: and zero for a relay, so they are checked for PSD instead of PD
PSD_BLOCKS = frozenset({"increment"})


def check_psd(m: np.ndarray, name: str) -> None:
    """WireError('not_pd') unless ``m`` (finite, symmetric) is positive semidefinite up to rounding."""
    scale = max(float(np.max(np.abs(m))), 1e-300)
    try:
        lowest = float(np.linalg.eigvalsh(m)[0])
    except np.linalg.LinAlgError:  # no convergence: no verdict, so no use
        lowest = math.nan
    if not lowest >= -1e-9 * scale:
        raise WireError("not_pd", f"{name}: not positive semidefinite")
