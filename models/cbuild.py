"""Small C sources compiled once with the system compiler and cached on disk.

The estimator's generated kernels (`estimators._symbolic`) and the simulator's contact merge
(`models.mujoco.contacts`) are C compiled into shared libraries kept in a cache folder
(``$WBC_HDMM_CACHE``, else ``$XDG_CACHE_HOME/wbc-hdmm``, else ``~/.cache/wbc-hdmm``), keyed by
the hash of the source, the compiler (``CC``, default ``cc``) and its options, and loaded
through ctypes. Callers keep a slower path for a machine without a compiler.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
from pathlib import Path

__all__ = ["cache_dir", "compile_shared"]


def cache_dir() -> Path:
    """The folder of the compiled libraries."""
    env = os.environ.get("WBC_HDMM_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "wbc-hdmm"


def compile_shared(source: str, name: str, opt: str = "-O2") -> Path:
    """The shared library of C ``source`` (compiled now, or found in the cache).

    Args:
        source: The C source.
        name: The library's base name.
        opt: The optimisation option.

    Raises:
        OSError, subprocess.SubprocessError: No compiler, or the source did not compile.
    """
    cc = os.environ.get("CC", "cc")
    digest = hashlib.sha256((source + cc + opt).encode()).hexdigest()[:20]
    cache = cache_dir()
    lib = cache / f"{name}_{digest}.so"
    if lib.exists():
        return lib
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        c_file = Path(tmp, name + ".c")
        c_file.write_text(source)
        tmp_lib = Path(tmp, lib.name)
        subprocess.run([cc, opt, "-fPIC", "-shared", "-o", str(tmp_lib), str(c_file), "-lm"],
                       check=True, capture_output=True, timeout=600)
        os.replace(tmp_lib, lib)  # atomic: concurrent builders agree on the content
    return lib
