"""Reading a session file's attributes, members and float64 datasets through h5py's
low-level API: the same values as the high-level API, at a fraction of its cost.

Why: ``obj.attrs[name]`` costs ~20 us (it asks the file for the attribute's shape and
type, builds a numpy dtype, a memory type and an array for each read), ``group[name]``
~25 us (it builds a ``File`` object to learn the file's mode); a 45-trial session has
~1400 attributes and ~600 items, so the high-level API alone took ~50 ms of the ~100 ms of
:func:`nmsid.protocols.session_reader.read_session`. The common cases here (a scalar
little-endian float64 or int64 attribute, a scalar variable-length string, a 1-D
float64 dataset) are read straight into a preallocated value; anything else (another
type, an array, an empty attribute, a fixed-length string as other labs' code writes)
goes through h5py's own high-level reading, so every value and type returned is what the
high-level API returns (``tests/protocols/test_session_h5.py`` holds them equal).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from nmsid.protocols.session_model import _h5py


class _Bound:
    """The one attribute h5py's ``AttributeManager`` takes from its parent: ``id``."""

    __slots__ = ("id",)

    def __init__(self, oid) -> None:
        self.id = oid


_TYPES: dict[str, Any] = {}


def _types() -> dict[str, Any]:
    """The file types read directly and their memory types (built once, on first use:
    h5py is imported lazily by the session modules)."""
    if not _TYPES:
        h5py = _h5py()
        h5t = h5py.h5t
        _TYPES.update(
            f64=h5t.IEEE_F64LE, i64=h5t.STD_I64LE,
            m_f64=h5t.py_create(np.dtype("<f8")), m_i64=h5t.py_create(np.dtype("<i8")),
            m_str={h5t.CSET_UTF8: h5t.py_create(h5py.string_dtype("utf-8")),
                   h5t.CSET_ASCII: h5t.py_create(h5py.string_dtype("ascii"))})
    return _TYPES


def _encoded(name: str | bytes) -> bytes:
    """A name as HDF5 stores it (h5py's rule: str as UTF-8, bytes as they are)."""
    return name if isinstance(name, bytes) else name.encode("utf8")


def _attr_names(oid) -> list[str | bytes]:
    """The attribute names of ``oid`` as iterating h5py's ``obj.attrs`` gives them (its
    order: creation order when the object tracks it, else by name; its decoding)."""
    h5py = _h5py()
    plist = oid.get_create_plist()
    tracked = plist.get_attr_creation_order() & h5py.h5p.CRT_ORDER_TRACKED
    plist.close()
    names: list[bytes] = []
    h5py.h5a.iterate(oid, lambda name, *_: names.append(name),
                     index_type=h5py.h5.INDEX_CRT_ORDER if tracked else h5py.h5.INDEX_NAME)
    out: list[str | bytes] = []
    for name in names:
        try:
            out.append(name.decode("utf8"))
        except UnicodeDecodeError:   # h5py keeps such a name as bytes
            out.append(name)
    return out


def read_attrs(oid, only: tuple[str, ...] | None = None) -> dict[str, Any]:
    """Every attribute of the object ``oid`` (a low-level h5py ObjectID), in h5py's order,
    as ``{name: obj.attrs[name]}`` would give them (same values, same types); ``only``:
    just these names, those present, in this order (the others are not read)."""
    h5py = _h5py()
    h5a, h5s, h5t = h5py.h5a, h5py.h5s, h5py.h5t
    types = _types()
    manager = h5py.AttributeManager(_Bound(oid))   # the fallback: h5py's own reading
    names = _attr_names(oid) if only is None else \
        [n for n in only if h5a.exists(oid, _encoded(n))]
    out: dict[Any, Any] = {}   # str keys (bytes for a name that is not UTF-8, as h5py)
    for name in names:
        attr = h5a.open(oid, _encoded(name))
        value: Any = None
        if attr.get_space().get_simple_extent_type() == h5s.SCALAR:
            tid = attr.get_type()
            cls = tid.get_class()
            if cls == h5t.FLOAT and tid.equal(types["f64"]):
                buf = np.empty((), np.float64)
                attr.read(buf, mtype=types["m_f64"])
                value = buf[()]
            elif cls == h5t.INTEGER and tid.equal(types["i64"]):
                buf = np.empty((), np.int64)
                attr.read(buf, mtype=types["m_i64"])
                value = buf[()]
            elif cls == h5t.STRING and tid.is_variable_str():
                mtype = types["m_str"].get(tid.get_cset())
                if mtype is not None:
                    obj = np.empty((), object)
                    attr.read(obj, mtype=mtype)
                    raw = obj[()]
                    # h5py decodes every variable-length string this way (attrs.py)
                    value = raw.decode("utf-8", "surrogateescape") \
                        if isinstance(raw, bytes) else None
        out[name] = manager[name] if value is None else value
    return out


def has_attr(oid, name: str) -> bool:
    """``name in obj.attrs`` for the low-level object ``oid``."""
    return bool(_h5py().h5a.exists(oid, _encoded(name)))


@dataclass(frozen=True)
class Member:
    """One item of a group, opened once, as the structural checks and the reader use it.

    Attributes
    ----------
    id : h5py ObjectID or None
        The open object (a ``DatasetID`` for a dataset); None once described only
        (:meth:`closed`).
    is_dataset : bool
    shape : tuple or None
        A dataset's shape (None for an empty dataspace); None for anything else.
    ndim : int
        A dataset's rank (0 for anything else).
    dtype : numpy.dtype or None
        A dataset's type; None for anything else.
    """

    id: Any
    is_dataset: bool
    shape: tuple[int, ...] | None
    ndim: int
    dtype: np.dtype | None

    def closed(self) -> Member:
        """This description without the open object (which closes when dropped)."""
        return Member(None, self.is_dataset, self.shape, self.ndim, self.dtype)

    @property
    def shown_shape(self) -> object:
        """What a message shows as its shape: the shape, or ``"a group"`` (the words the
        checks always used for an item that is not a dataset)."""
        return self.shape if self.is_dataset else "a group"


def open_member(gid, name: str) -> Member:
    """Open ``name`` in the group ``gid`` (a low-level GroupID) as a :class:`Member`."""
    h5py = _h5py()
    oid = h5py.h5o.open(gid, _encoded(name))
    if h5py.h5i.get_type(oid) != h5py.h5i.DATASET:
        return Member(oid, False, None, 0, None)
    space = oid.get_space()   # once: DatasetID.shape and .rank would each ask for it
    return Member(oid, True, space.shape, space.get_simple_extent_ndims(), oid.dtype)


def open_group(gid, name: str):
    """The low-level GroupID of ``name`` in ``gid``, or None when it is not a group."""
    h5py = _h5py()
    oid = h5py.h5o.open(gid, _encoded(name))
    return oid if h5py.h5i.get_type(oid) == h5py.h5i.GROUP else None


def is_plain_float64(member: Member) -> bool:
    """True for a non-empty 1-D little-endian float64 dataset (read by
    :func:`read_float64` straight into a float64 array)."""
    return bool(member.is_dataset and member.dtype == np.dtype("<f8") and member.ndim == 1
                and member.shape and member.shape[0] > 0)


def float64_buffers(members: list[Member]) -> dict[int, np.ndarray]:
    """One float64 array for all ``members`` that :func:`is_plain_float64`, cut into a
    view per member (keyed by ``id(member)``) for :func:`read_float64` to fill.

    One allocation instead of one per dataset: a fresh process's first read of a session
    otherwise faults in every 4 kB page of ~90 separate arrays (a large numpy array is
    given transparent huge pages where the system offers them); ~5 ms of a 45-trial
    session's first read (``bench/bench_identify_io.py``)."""
    plain = [m for m in members if is_plain_float64(m)]
    whole = np.empty(sum(m.shape[0] for m in plain if m.shape), np.float64)
    views: dict[int, np.ndarray] = {}
    start = 0
    for m in plain:
        n = m.shape[0] if m.shape else 0
        views[id(m)] = whole[start:start + n]
        start += n
    return views


def read_float64(member: Member, out: np.ndarray | None = None) -> np.ndarray:
    """A dataset's samples as float64, as ``np.asarray(dataset[()], dtype=np.float64)``
    gives them: a 1-D little-endian float64 dataset is read into a preallocated array
    (``out``, of its shape, when given; its Fletcher-32 checksums verified as by any
    read), anything else through h5py."""
    h5py = _h5py()
    if is_plain_float64(member) and member.shape is not None:
        if out is None or out.shape != member.shape or out.dtype != np.float64:
            out = np.empty(member.shape, np.float64)
        member.id.read(h5py.h5s.ALL, h5py.h5s.ALL, out, mtype=_types()["m_f64"])
        return out
    return np.asarray(h5py.Dataset(member.id, readonly=True)[()], dtype=np.float64)
