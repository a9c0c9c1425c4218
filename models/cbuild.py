"""Small C sources compiled once with the system compiler and cached on disk.

The estimator's generated kernels (`estimators._symbolic`) and the simulator's contact merge
(`models.mujoco.contacts`) are C compiled into shared libraries kept in a cache folder
(``$WBC_HDMM_CACHE``, else ``$XDG_CACHE_HOME/wbc-hdmm``, else ``~/.cache/wbc-hdmm``), keyed by
the hash of the source, the compiler (``CC``, default ``cc``), its options and the host's
CPU, and loaded through ctypes. Callers keep a slower path for a machine without a compiler.

The libraries are built for the host's instruction set (``-march=native``) with the
contraction of products and sums into fused multiply-adds off (``-ffp-contract=off``): the
vector units make the estimator's kernels 10-20 % faster, and every result keeps the bits of
the portable build (IEEE operations in the source's order, no reassociation, no FMA
rounding; `tests/test_cbuild.py` compares the two). A compiler that rejects the host options
gets the portable build.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import os
import platform
import subprocess
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["BufferSlot", "HOST_OPTIONS", "address", "bind", "cache_dir", "compile_shared",
           "load_shared", "mujoco_options"]

_log = logging.getLogger(__name__)

HOST_OPTIONS = ("-march=native", "-ffp-contract=off")
_CPU_KEYS = ("model name", "flags", "Features", "CPU part")  # x86; arm


@functools.cache
def _host_id() -> str:
    """What a library built for this host's CPU depends on: its architecture, model, flags.

    Read once per process (every library loaded asks for it).
    """
    lines = []
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key = line.split(":", 1)[0].strip()
                if key in _CPU_KEYS and line not in lines:
                    lines.append(line)
                elif not line.strip() and lines:
                    break  # the first processor's block is enough
    except OSError:
        pass
    return platform.machine() + platform.processor() + "".join(lines)


def cache_dir() -> Path:
    """The folder of the compiled libraries."""
    env = os.environ.get("WBC_HDMM_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "wbc-hdmm"


@functools.cache
def mujoco_options() -> tuple[str, ...]:
    """Compiler options of a source that calls MuJoCo's C API (``#include <mujoco/mujoco.h>``).

    The headers and the library of the installed ``mujoco`` package: the library the Python
    bindings have loaded already, so the compiled code and the bindings share one MuJoCo
    (the bindings' ``MjModel._address`` and ``MjData._address`` are its ``mjModel*`` and
    ``mjData*``). Its file name carries the version, so the cache key does too.

    Raises:
        OSError: The package has no headers or no library.
    """
    import mujoco

    root = Path(mujoco.__file__).parent
    libs = sorted(root.glob("libmujoco.so*"))
    if not (root / "include" / "mujoco" / "mujoco.h").exists() or not libs:
        raise OSError(f"no MuJoCo headers or library under {root}")
    return (f"-I{root / 'include'}", str(libs[-1]), f"-Wl,-rpath,{root}")


def compile_shared(source: str, name: str, opt: str = "-O2", host: bool = True,
                   mujoco: bool = False) -> Path:
    """The shared library of C ``source`` (compiled now, or found in the cache).

    Args:
        source: The C source.
        name: The library's base name.
        opt: The optimisation option.
        host: Build for this host's CPU (`HOST_OPTIONS`), falling back to the portable
            build if the compiler rejects them; False: the portable build.
        mujoco: The source calls MuJoCo's C API (`mujoco_options`).

    Raises:
        OSError, subprocess.SubprocessError: No compiler, or the source did not compile.
    """
    extra = list(mujoco_options()) if mujoco else []
    if host:
        try:
            return _build(source, name, [opt, *HOST_OPTIONS], _host_id(), extra)
        except subprocess.CalledProcessError:
            pass  # e.g. a compiler without -march=native: the portable build
    return _build(source, name, [opt], "", extra)


def _build(source: str, name: str, options: list[str], host_id: str,
           extra: list[str]) -> Path:
    cc = os.environ.get("CC", "cc")
    digest = hashlib.sha256("\0".join([source, cc, *options, *extra, host_id]).encode()
                            ).hexdigest()
    cache = cache_dir()
    lib = cache / f"{name}_{digest[:20]}.so"
    if lib.exists():
        return lib
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        c_file = Path(tmp, name + ".c")
        c_file.write_text(source)
        tmp_lib = Path(tmp, lib.name)
        subprocess.run([cc, *options, "-fPIC", "-shared", "-o", str(tmp_lib), str(c_file),
                        *extra, "-lm"], check=True, capture_output=True, timeout=600)
        os.replace(tmp_lib, lib)  # atomic: concurrent builders agree on the content
    return lib


_LOADED: dict = {}  # (name, opt, source) -> the library or None, once per process


def load_shared(source: str, name: str, functions: dict, fallback: str,
                opt: str = "-O2", mujoco: bool = False) -> ctypes.CDLL | None:
    """`compile_shared`'s library loaded once per process, its functions' signatures set.

    Args:
        source: The C source.
        name: The library's base name.
        functions: Function name -> ``(argtypes, restype)``.
        fallback: What the caller runs instead, for the warning without a compiler.
        opt: The optimisation option.
        mujoco: The source calls MuJoCo's C API (`compile_shared`).

    Returns:
        The library, or None (logged once) when there is no working compiler or the source
        does not compile: the caller then runs its own slower path.
    """
    key = (name, opt, source)
    if key not in _LOADED:
        try:
            lib = ctypes.CDLL(str(compile_shared(source, name, opt, mujoco=mujoco)))
            for fun_name, (argtypes, restype) in functions.items():
                fun = getattr(lib, fun_name)
                fun.argtypes, fun.restype = list(argtypes), restype
        except (OSError, subprocess.SubprocessError) as exc:
            _log.warning("%s not compiled (%s); using %s", name, exc, fallback)
            lib = None
        _LOADED[key] = lib
    return _LOADED[key]


_char_view = ctypes.c_char.from_buffer


def address(a: np.ndarray) -> int:
    """``a.ctypes.data`` at a fifth of its cost (0.2 us) for a writable contiguous array.

    A ctypes call with a few arrays spends most of its Python time on their addresses:
    ``ndarray.ctypes`` runs numpy's Python helper; a ctypes view of the buffer does not.
    Read-only, strided or empty arrays take ``a.ctypes.data``.
    """
    try:
        return ctypes.addressof(_char_view(a))
    except (TypeError, ValueError, BufferError):
        return a.ctypes.data


def bind(fun, *args):
    """``fun`` with its arguments bound: an array by its data's address, anything else as is.

    The cheapest per-tick call through ctypes (no argument conversion left); the arrays must
    outlive the returned callable and keep their buffers (the caller holds them).
    """
    return functools.partial(fun, *(a.ctypes.data if isinstance(a, np.ndarray) else a
                                    for a in args))


class BufferSlot:
    """A number kept in one slot of an array attribute that C code reads and writes.

    ``x = BufferSlot("_state", 0)`` in a class body makes ``obj.x`` read
    ``kind(obj._state[0])`` and ``obj.x = v`` write ``obj._state[0] = v``: a filter's state
    that a compiled pass updates in place stays an attribute to the Python around it.
    """

    def __init__(self, buffer: str, index: int, kind: type = float, doc: str | None = None):
        self.buffer, self.index, self.kind = buffer, index, kind
        self.__doc__ = doc

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return self.kind(getattr(obj, self.buffer)[self.index])

    def __set__(self, obj, value) -> None:
        getattr(obj, self.buffer)[self.index] = value
