"""numpy arrays and tuples read in C: checks of a tick's objects without their Python cost.

A ctypes call spends most of its Python time on its arguments: an array's address through
``ndarray.ctypes`` or a ctypes view of its buffer (~0.3 us each), its shape and dtype checked
in Python. Passed as objects (``ctypes.py_object``), they cost nothing to pass, and the C
reads the fields numpy and CPython keep at fixed places of their objects: an array's data,
dimensions, flags and type (numpy's ``PyArrayObject_fields``, ``PyArray_Descr``), a
tuple's size and items (CPython's ``PyTupleObject``). `fields_readable` checks once per
process that the C finds there what numpy and Python say of a few objects; where it does
not (another numpy or Python build), the callers keep their Python checks.

* `ARRAY_FIELDS_C`: ``array_data``, the data of a C-ordered, aligned, native float64 array
  of a given shape, else NULL (`wbc.tasks.linear_c` includes it).
* `SameObjects`: whether a tuple holds given objects, its arrays still read-only
  (`wbc.qp.QPBuilder`'s guard of the tasks' terms).
"""

from __future__ import annotations

import copy
import ctypes
import functools
import logging
import subprocess

import numpy as np

from models.cbuild import bind, compile_shared

__all__ = ["ARRAY_FIELDS_C", "OBJECT_FIELDS_C", "SameObjects", "fields_readable"]

_log = logging.getLogger(__name__)

ARRAY_FIELDS_C = r"""
/* numpy's PyArrayObject_fields up to its flags (a CPython object's head first), and where
   its PyArray_Descr keeps byteorder and type_num (`fields_readable` checks them). */
typedef struct {
  long long refcnt; const void* type; char* data; int nd; const long long* dims;
  const long long* strides; const void* base; const char* descr; int flags;
} np_array;
enum { C_ALIGNED = 0x0001 | 0x0100, WRITEABLE = 0x0400, NPY_DOUBLE = 12, BYTEORDER = 26,
       TYPE_NUM = 28 };

/* The data of `obj` if it is an ndarray (not a subclass), C-ordered, aligned, native
   float64 of shape (d0,) (nd 1) or (d0, d1) (nd 2); else NULL. */
static char* array_data(const void* obj, const void* ndarray, int nd, long long d0,
                        long long d1) {
  const np_array* a = (const np_array*)obj;
  if (a->type != ndarray || a->nd != nd || a->dims[0] != d0 || (nd == 2 && a->dims[1] != d1)
      || (a->flags & C_ALIGNED) != C_ALIGNED || a->descr[BYTEORDER] != '='
      || *(const int*)(a->descr + TYPE_NUM) != NPY_DOUBLE)
    return 0;
  return a->data;
}
"""

OBJECT_FIELDS_C = ARRAY_FIELDS_C + r"""
/* A tuple's items (CPython's PyTupleObject: its head, its size, the items). */
typedef struct { long long refcnt; const void* type; long long size; const void* items[]; }
    py_tuple;

void array_probe(const void* obj, long long* out) {
  const np_array* a = (const np_array*)obj;
  out[0] = (long long)a->data; out[1] = a->nd; out[2] = a->dims[0];
  out[3] = a->nd > 1 ? a->dims[1] : -1; out[4] = a->flags & (C_ALIGNED | WRITEABLE);
  out[5] = *(const int*)(a->descr + TYPE_NUM); out[6] = a->descr[BYTEORDER];
  out[7] = (long long)a->type;
}

long long tuple_probe(const void* t, long long i) {
  return i < 0 ? ((const py_tuple*)t)->size : (long long)((const py_tuple*)t)->items[i];
}

/* 1 if tuple `t` holds the objects `kept` (count of them), each one flagged in `arrays`
   an ndarray that is still read-only; else 0. */
int same_objects(const unsigned long long* kept, const unsigned char* arrays, long long count,
                 const void* t) {
  const py_tuple* tuple = (const py_tuple*)t;
  long long i;
  if (tuple->size != count) return 0;
  for (i = 0; i < count; ++i)
    if ((unsigned long long)tuple->items[i] != kept[i]
        || (arrays[i] && (((const np_array*)tuple->items[i])->flags & WRITEABLE)))
      return 0;
  return 1;
}
"""

_P, _O, _LL = ctypes.c_void_p, ctypes.py_object, ctypes.c_longlong


@functools.cache
def _library() -> ctypes.PyDLL | None:
    """`OBJECT_FIELDS_C` as a `ctypes.PyDLL` (it reads Python objects: the GIL held)."""
    try:
        lib = ctypes.PyDLL(str(compile_shared(OBJECT_FIELDS_C, "object_fields")))
    except (OSError, subprocess.SubprocessError) as exc:
        _log.warning("object_fields not compiled (%s); checks stay in Python", exc)
        return None
    lib.array_probe.argtypes, lib.array_probe.restype = [_O, _P], None
    lib.tuple_probe.argtypes, lib.tuple_probe.restype = [_O, _LL], _LL
    lib.same_objects.argtypes, lib.same_objects.restype = [_P, _P, _LL, _O], ctypes.c_int
    return lib


@functools.cache
def fields_readable() -> bool:
    """Whether the C reads what numpy and Python say of a few arrays and a tuple.

    Compiled, and the structs of `OBJECT_FIELDS_C` where this process's numpy and CPython
    keep those fields (a 64-bit build of CPython with numpy's own layout: checked on
    arrays of each kind ``array_data`` tells apart, and on a tuple).
    """
    lib = _library()
    if lib is None:
        return False
    base = np.zeros((4, 6))
    base.setflags(write=False)
    arrays = (np.zeros((3, 4)), np.zeros(5), base, base[:, ::2], np.zeros(3, np.float32),
              np.zeros(3, ">f8"), np.zeros((2, 3), order="F"))
    out = np.zeros(8, np.int64)
    for a in arrays:
        lib.array_probe(a, out.ctypes.data)
        flags = (a.flags.c_contiguous * 0x0001 | a.flags.aligned * 0x0100
                 | a.flags.writeable * 0x0400)
        want = (a.ctypes.data, a.ndim, a.shape[0], a.shape[1] if a.ndim > 1 else -1, flags,
                a.dtype.num, ord(a.dtype.byteorder), id(np.ndarray))
        if tuple(int(v) for v in out) != want:
            return False
    items = (object(), np.zeros(2), None)
    return (lib.tuple_probe(items, -1) == 3
            and all(lib.tuple_probe(items, i) == id(x) for i, x in enumerate(items))
            and np.dtype(np.float64).num == 12 and np.dtype(np.float64).byteorder == "=")


class SameObjects:
    """A check that a tuple holds the given objects, and that its arrays are read-only.

    ``SameObjects.make(objects)(t)``: whether ``t`` (a tuple) holds the very objects of
    ``objects`` in order, each array among them still read-only: one C call
    (`wbc.qp.QPBuilder`'s guard of the tasks' terms). The objects are kept (their
    addresses compared). ``call(t)``: the same as the C's int (1 or 0), without this
    object's method call.
    """

    def __init__(self, objects: tuple):
        self.objects = objects
        self._kept = np.array([id(x) for x in objects] or [0], np.uint64)
        self._arrays = np.array([isinstance(x, np.ndarray) for x in objects] or [0], np.uint8)
        self.call = bind(_library().same_objects, self._kept, self._arrays, len(objects))

    @classmethod
    def make(cls, objects: tuple) -> SameObjects | None:
        """The check of ``objects``; None where `fields_readable` is not."""
        return cls(tuple(objects)) if fields_readable() else None

    def __deepcopy__(self, memo) -> SameObjects:
        """A check of its own: of the copied objects, its call bound to its own arrays."""
        new = SameObjects(copy.deepcopy(self.objects, memo))
        memo[id(self)] = new
        return new

    def __call__(self, t: tuple) -> bool:
        """Whether tuple ``t`` holds the objects, its arrays read-only."""
        return self.call(t) == 1
