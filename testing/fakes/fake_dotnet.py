"""Fake ``System`` names of pythonnet: typed integers and arrays, range-checked like pythonnet
(an out-of-range item raises ``OverflowError``), and the exceptions McsUsbNet raises."""

from __future__ import annotations

import numpy as np


class _NetInt(int):
    MIN, MAX, NAME = 0, 0, ""

    def __new__(cls, value):
        if isinstance(value, float) and not float(value).is_integer():
            raise TypeError(f"cannot convert {value!r} to System.{cls.NAME}")
        v = int(value)
        if not cls.MIN <= v <= cls.MAX:
            raise OverflowError(f"value {v} out of range for System.{cls.NAME}")
        return super().__new__(cls, v)


class Int32(_NetInt):
    MIN, MAX, NAME = -2 ** 31, 2 ** 31 - 1, "Int32"


class UInt32(_NetInt):
    MIN, MAX, NAME = 0, 2 ** 32 - 1, "UInt32"


class Int16(_NetInt):
    MIN, MAX, NAME = -2 ** 15, 2 ** 15 - 1, "Int16"


class UInt16(_NetInt):
    MIN, MAX, NAME = 0, 2 ** 16 - 1, "UInt16"


class UInt64(_NetInt):
    MIN, MAX, NAME = 0, 2 ** 64 - 1, "UInt64"


class NetArray:
    """``System.Array[T]``: a typed, fixed-length array (items range-checked)."""

    def __init__(self, element_type, items):
        self.element_type = element_type
        arr = np.asarray(items.tolist() if isinstance(items, np.ndarray) else list(items))
        if arr.size and arr.dtype.kind not in "iu":
            if arr.dtype.kind != "f" or not np.all(np.mod(arr, 1) == 0):
                raise TypeError(f"non-integer item for System.{element_type.NAME}[]")
        arr = arr.astype(np.int64)
        if arr.size and (int(arr.min()) < element_type.MIN or int(arr.max()) > element_type.MAX):
            raise OverflowError(f"item out of range for System.{element_type.NAME}[]")
        self.values = arr

    def __len__(self):
        return len(self.values)

    def __getitem__(self, i):
        return self.values[i]

    def __iter__(self):
        return iter(self.values.tolist())


class _ArrayFactory:
    def __getitem__(self, element_type):
        return lambda items: NetArray(element_type, items)


def _require(value, kind, what, array=False):
    if kind is UInt32 and not array:
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2 ** 32:
            raise TypeError(f"{what}: expected System.UInt32, got {value!r}")
        return int(value)
    if not isinstance(value, NetArray) or value.element_type is not kind:
        raise TypeError(f"{what}: expected System.{kind.NAME}[], got {type(value).__name__}")
    return value.values


class CUsbExceptionNet(RuntimeError):
    """``Mcs.Usb.CUsbExceptionNet`` as pythonnet raises it."""


class ObjectDisposedException(RuntimeError):
    """``System.ObjectDisposedException``."""
