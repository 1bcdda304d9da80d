"""NumPy arrays to and from ``PackedArray`` messages, with strict validation.

On the wire an array is its shape, a dtype name from ``DTYPES`` and its elements as
C-order little-endian bytes (see liquidtwin.proto). Unpacking checks every claim the
message makes before touching the bytes and never unpickles anything, so a malformed
or hostile message ends in an ``ArrayError`` (a ``ValueError``) whose ``code`` is the
``Error.Code`` a server should answer with.
"""

from __future__ import annotations

import math

import numpy as np

from .liquidtwin_pb2 import Error, PackedArray

#: Wire dtype name -> little-endian NumPy dtype. Only these cross the wire.
DTYPES: dict[str, np.dtype] = {
    name: np.dtype(name).newbyteorder("<")
    for name in (
        "bool",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "float16",
        "float32",
        "float64",
    )
}

#: Default limit on an array's payload, bytes (256 MiB).
DEFAULT_MAX_BYTES = 256 * 1024 * 1024

#: Most dimensions an array may have.
MAX_NDIM = 32

_MAX_DIM = 2**32 - 1  # shape entries are uint32 on the wire


class ArrayError(ValueError):
    """An array or ``PackedArray`` that cannot cross the wire.

    Attributes:
        code: the ``Error.Code`` that describes the failure (BAD_REQUEST, TOO_LARGE or
            NON_FINITE), for a server's ``reply_err``.
    """

    def __init__(self, message: str, code: int = Error.BAD_REQUEST):
        super().__init__(message)
        self.code = code


def pack_array(
    array: np.ndarray, *, max_bytes: int = DEFAULT_MAX_BYTES, require_finite: bool = False
) -> PackedArray:
    """Pack an array into a ``PackedArray``.

    Args:
        array: any array-like of a dtype in ``DTYPES``, any byte order and memory layout;
            shape (d0, ..., dk) with k < ``MAX_NDIM``, 0-d and empty arrays included.
        max_bytes: refuse arrays whose payload exceeds this many bytes.
        require_finite: refuse floating-point arrays holding NaN or infinity.

    Returns:
        A ``PackedArray`` holding ``shape``, the dtype name and prod(shape) * itemsize
        bytes, C order, little-endian.

    Raises:
        ArrayError: unsupported dtype, too many dimensions, a dimension over 2**32 - 1,
            payload over ``max_bytes`` (code TOO_LARGE) or non-finite values (NON_FINITE).
    """
    a = np.asarray(array)
    name = a.dtype.name
    if name not in DTYPES or a.dtype.fields is not None:
        raise ArrayError(f"cannot pack dtype {a.dtype!s}; supported: {', '.join(DTYPES)}")
    _check_shape(a.shape)
    _check_size(a.nbytes, max_bytes)
    if require_finite:
        _check_finite(a)
    data = a.astype(DTYPES[name], copy=False).tobytes(order="C")
    return PackedArray(shape=a.shape, dtype=name, data=data)


def unpack_array(
    message: PackedArray, *, max_bytes: int = DEFAULT_MAX_BYTES, require_finite: bool = False
) -> np.ndarray:
    """Validate a ``PackedArray`` and return its contents as a new array.

    Args:
        message: a ``liquidtwin.v1.PackedArray``.
        max_bytes: refuse payloads (claimed or actual) over this many bytes.
        require_finite: refuse floating-point arrays holding NaN or infinity.

    Returns:
        A writable, C-contiguous array in native byte order, of ``message.shape`` and the
        dtype named by ``message.dtype``; it does not share memory with the message.

    Raises:
        ArrayError: unknown dtype, too many dimensions, payload length that does not
            match shape x itemsize, bool bytes other than 0/1 (all BAD_REQUEST), payload
            over ``max_bytes`` (TOO_LARGE), non-finite values (NON_FINITE).
        TypeError: ``message`` is not a PackedArray.
    """
    full_name = getattr(getattr(message, "DESCRIPTOR", None), "full_name", None)
    if full_name != PackedArray.DESCRIPTOR.full_name:
        raise TypeError(f"expected a liquidtwin.v1.PackedArray, got {type(message).__name__}")
    wire = DTYPES.get(message.dtype)
    if wire is None:
        raise ArrayError(
            f"unsupported dtype {message.dtype!r}; expected one of: {', '.join(DTYPES)}"
        )
    shape = tuple(message.shape)
    _check_shape(shape)
    expected = math.prod(shape) * wire.itemsize
    data = message.data
    _check_size(max(expected, len(data)), max_bytes)
    if len(data) != expected:
        raise ArrayError(
            f"payload holds {len(data)} bytes but shape {shape} of {message.dtype} "
            f"needs {expected}"
        )
    if wire.kind == "b" and expected and np.frombuffer(data, dtype=np.uint8).max() > 1:
        raise ArrayError("bool payload holds bytes other than 0 and 1")
    out = np.frombuffer(data, dtype=wire).reshape(shape).astype(message.dtype, copy=True)
    if require_finite:
        _check_finite(out)
    return out


def _check_shape(shape: tuple[int, ...]) -> None:
    if len(shape) > MAX_NDIM:
        raise ArrayError(f"array has {len(shape)} dimensions; at most {MAX_NDIM} allowed")
    if any(d > _MAX_DIM for d in shape):
        raise ArrayError(f"shape {tuple(shape)} has a dimension over {_MAX_DIM}")


def _check_size(nbytes: int, max_bytes: int) -> None:
    if nbytes > max_bytes:
        raise ArrayError(
            f"array payload of {nbytes} bytes exceeds the limit of {max_bytes} bytes",
            Error.TOO_LARGE,
        )


def _check_finite(a: np.ndarray) -> None:
    if a.dtype.kind != "f":
        return
    bad = a.size - int(np.count_nonzero(np.isfinite(a)))
    if bad:
        raise ArrayError(
            f"array holds {bad} non-finite value(s) (NaN or infinity)", Error.NON_FINITE
        )
