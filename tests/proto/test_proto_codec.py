"""pack_array / unpack_array: round trips and every rejection path."""

import numpy as np
import pytest

from liquidtwin_proto import (DTYPES, MAX_NDIM, ArrayError, Error, PackedArray, pack_array,
                              unpack_array)


def _through_wire(message: PackedArray) -> PackedArray:
    return PackedArray.FromString(message.SerializeToString())


@pytest.mark.parametrize("dtype", sorted(DTYPES))
@pytest.mark.parametrize("shape", [(), (0,), (5,), (2, 3), (2, 0, 4), (1, 2, 1, 3)])
def test_round_trip_every_dtype_and_shape(dtype, shape):
    rng = np.random.default_rng(0)
    a = (rng.standard_normal(shape) * 50).astype(dtype)
    out = unpack_array(_through_wire(pack_array(a)))
    assert out.dtype == np.dtype(dtype)
    assert out.shape == shape
    np.testing.assert_array_equal(out, a)


def test_zero_d_and_empty_payloads():
    scalar = pack_array(np.float64(2.5))
    assert list(scalar.shape) == [] and len(scalar.data) == 8
    assert unpack_array(scalar).ndim == 0 and unpack_array(scalar)[()] == 2.5
    empty = pack_array(np.zeros((0, 3), np.float32))
    assert list(empty.shape) == [0, 3] and empty.data == b""
    assert unpack_array(empty).shape == (0, 3)


def test_big_endian_input_is_sent_little_endian():
    a = np.array([1.0, -2.0, 3.5], dtype=">f8")
    m = pack_array(a)
    assert m.dtype == "float64"
    assert m.data == np.array([1.0, -2.0, 3.5], dtype="<f8").tobytes()
    out = unpack_array(m)
    assert out.dtype == np.dtype("float64") and out.dtype.isnative
    np.testing.assert_array_equal(out, a)


def test_non_contiguous_input_is_packed_in_c_order():
    a = np.arange(12, dtype=np.int32).reshape(3, 4).T[:, ::2]
    out = unpack_array(pack_array(a))
    np.testing.assert_array_equal(out, a)
    assert out.flags.c_contiguous


def test_result_is_writable_and_owns_its_memory():
    m = pack_array(np.arange(4, dtype=np.float32))
    out = unpack_array(m)
    out[0] = 99.0
    assert out.flags.writeable
    np.testing.assert_array_equal(unpack_array(m), [0, 1, 2, 3])


@pytest.mark.parametrize(
    "value",
    [np.array([1 + 2j]), np.array(["a"]), np.array([object()], dtype=object),
     np.zeros(2, dtype=[("x", "<f4")]), np.array(["2020-01-01"], dtype="datetime64[D]")],
    ids=["complex", "str", "object", "structured", "datetime"],
)
def test_pack_rejects_unsupported_dtypes(value):
    with pytest.raises(ArrayError, match="cannot pack dtype") as info:
        pack_array(value)
    assert info.value.code == Error.BAD_REQUEST


@pytest.mark.parametrize("dtype", ["float128", "<f4", "", "object", "complex64"])
def test_unpack_rejects_unknown_dtype_names(dtype):
    m = PackedArray(shape=[1], dtype=dtype, data=b"\0" * 4)
    with pytest.raises(ArrayError, match="unsupported dtype"):
        unpack_array(m)


def test_unpack_rejects_truncated_and_padded_data():
    m = pack_array(np.ones((4, 3), np.float32))
    short = PackedArray(shape=m.shape, dtype=m.dtype, data=m.data[:-1])
    with pytest.raises(ArrayError, match="payload holds 47 bytes .* needs 48"):
        unpack_array(short)
    long = PackedArray(shape=m.shape, dtype=m.dtype, data=m.data + b"\0")
    with pytest.raises(ArrayError, match="needs 48"):
        unpack_array(long)


def test_pack_rejects_oversize():
    with pytest.raises(ArrayError, match="exceeds the limit of 100 bytes") as info:
        pack_array(np.zeros(26, np.float32), max_bytes=100)
    assert info.value.code == Error.TOO_LARGE
    assert len(pack_array(np.zeros(25, np.float32), max_bytes=100).data) == 100


def test_unpack_rejects_huge_claimed_shape_before_allocating():
    m = PackedArray(shape=[2**32 - 1, 2**32 - 1, 2**32 - 1], dtype="float64", data=b"")
    with pytest.raises(ArrayError, match="exceeds the limit") as info:
        unpack_array(m)
    assert info.value.code == Error.TOO_LARGE


def test_unpack_rejects_oversize_payload_even_if_shape_is_small():
    m = PackedArray(shape=[1], dtype="uint8", data=b"\0" * 1000)
    with pytest.raises(ArrayError) as info:
        unpack_array(m, max_bytes=512)
    assert info.value.code == Error.TOO_LARGE


def test_non_finite_check_is_optional():
    a = np.array([[0.0, np.nan], [np.inf, -np.inf]], np.float32)
    np.testing.assert_array_equal(unpack_array(pack_array(a)), a)
    with pytest.raises(ArrayError, match="3 non-finite") as info:
        pack_array(a, require_finite=True)
    assert info.value.code == Error.NON_FINITE
    with pytest.raises(ArrayError, match="3 non-finite") as info:
        unpack_array(pack_array(a), require_finite=True)
    assert info.value.code == Error.NON_FINITE
    ints = np.arange(3)
    np.testing.assert_array_equal(unpack_array(pack_array(ints, require_finite=True),
                                               require_finite=True), ints)


def test_unpack_rejects_bool_bytes_other_than_zero_and_one():
    with pytest.raises(ArrayError, match="bool payload"):
        unpack_array(PackedArray(shape=[3], dtype="bool", data=b"\x00\x01\x02"))


def test_too_many_dimensions():
    with pytest.raises(ArrayError, match="dimensions"):
        unpack_array(PackedArray(shape=[1] * (MAX_NDIM + 1), dtype="uint8", data=b"\0"))
    with pytest.raises(ArrayError, match="dimensions"):
        pack_array(np.zeros((1,) * (MAX_NDIM + 1), np.uint8))


def test_unpack_requires_a_packed_array():
    with pytest.raises(TypeError, match="PackedArray"):
        unpack_array(b"\x08\x01")
    with pytest.raises(TypeError, match="PackedArray"):
        unpack_array(Error())


def test_array_error_is_a_value_error():
    assert issubclass(ArrayError, ValueError)
