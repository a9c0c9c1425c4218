"""The C build: libraries for the host's CPU keep the portable build's bits."""

import ctypes
import os
import shutil
import stat

import numpy as np
import pytest

from models.cbuild import compile_shared

# Products and sums a compiler would contract into fused multiply-adds, a square root and a
# reduction: what the generated kernels are made of.
SOURCE = """
#include <math.h>
void f(const double *x, double *y, int n) {
    double s = 0.0;
    for (int i = 0; i < n; ++i) {
        y[i] = x[i] * x[(i + 1) % n] + x[(i + 2) % n] * 1.000000119 - sqrt(fabs(x[i]));
        s += y[i] * x[i];
    }
    y[n] = s;
}
"""


def _run(lib, x):
    fn = ctypes.CDLL(str(lib)).f
    y = np.empty(len(x) + 1)
    fn(x.ctypes.data_as(ctypes.c_void_p), y.ctypes.data_as(ctypes.c_void_p),
       ctypes.c_int(len(x)))
    return y


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("WBC_HDMM_CACHE", str(tmp_path / "cache"))
    if shutil.which(os.environ.get("CC", "cc")) is None:
        pytest.skip("no C compiler")
    return tmp_path


def test_host_build_keeps_the_portable_bits(cache):
    host = compile_shared(SOURCE, "fma_probe")
    portable = compile_shared(SOURCE, "fma_probe", host=False)
    assert host != portable
    x = np.random.default_rng(0).normal(size=4096) * 1e3
    np.testing.assert_array_equal(_run(host, x), _run(portable, x))


def test_estimator_kernel_host_build_keeps_the_portable_bits(cache):
    from estimators import NormalForceEstimator
    from estimators._kernel_calls import Compiled
    from models import build_reference_machine
    from testkit.estimator_states import random_state

    machine = build_reference_machine()
    est = NormalForceEstimator(machine)
    fun = est._kernels.functions["nf_estimate"]
    rows = []
    rng = np.random.default_rng(1)
    for _ in range(64):
        inp = np.zeros(fun.size1_in(0))
        est._packer.fill(inp, random_state(machine, rng, max_tilt=0.3), est.D, est.beta)
        rows.append(inp)
    x = np.array(rows)
    outs = []
    for host in (True, False):
        src = est._kernels.source("nf_estimate")
        lib = compile_shared(src, "nf_estimate", "-O2", host=host)
        out = np.empty((len(x), fun.size1_out(0)))
        Compiled(ctypes.CDLL(str(lib)), fun).batch(x, out)
        outs.append(out)
    assert np.isfinite(outs[0]).all()
    np.testing.assert_array_equal(outs[0], outs[1])


def test_compiler_without_host_options_gets_the_portable_build(cache):
    cc = os.environ.get("CC", "cc")
    wrapper = cache / "cc-no-native"
    wrapper.write_text("#!/bin/sh\nfor a in \"$@\"; do case $a in -march=*) "
                       "echo 'unknown option' >&2; exit 1;; esac; done\n"
                       f"exec {shutil.which(cc)} \"$@\"\n")
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IEXEC)
    os.environ["CC"] = str(wrapper)
    try:
        lib = compile_shared(SOURCE, "fma_probe")
        portable = compile_shared(SOURCE, "fma_probe", host=False)
    finally:
        os.environ["CC"] = cc
    assert lib == portable
    x = np.linspace(-2.0, 3.0, 64)
    np.testing.assert_array_equal(_run(lib, x), _run(compile_shared(SOURCE, "fma_probe"), x))


def test_load_shared_sets_signatures_loads_once_and_falls_back_without_a_compiler(
        tmp_path, monkeypatch, caplog):
    from models.cbuild import load_shared

    monkeypatch.setenv("WBC_HDMM_CACHE", str(tmp_path / "cache"))
    source = "double twice(double x) { return 2.0 * x; }\n"
    signatures = {"twice": ([ctypes.c_double], ctypes.c_double)}
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    assert load_shared(source + "/* a */", "probe", signatures, "Python") is None
    assert "probe not compiled" in caplog.text and "using Python" in caplog.text
    monkeypatch.delenv("CC")
    if shutil.which("cc") is None:
        pytest.skip("no C compiler")
    lib = load_shared(source, "probe", signatures, "Python")
    assert lib.twice(1.25) == 2.5  # the signature set: a double, not an int
    assert load_shared(source, "probe", signatures, "Python") is lib


def test_a_buffer_slot_reads_and_writes_its_array():
    """`BufferSlot`: the attribute is the array's slot, in its kind, both ways."""
    import numpy as np

    from models.cbuild import BufferSlot

    class Counter:
        n = BufferSlot("_buf", 1, int)
        x = BufferSlot("_buf", 0, doc="a float")

        def __init__(self):
            self._buf = np.array([0.5, 3.0])

    c = Counter()
    assert (c.n, c.x) == (3, 0.5) and type(c.n) is int and type(c.x) is float
    c.n += 2
    c.x = -1.25
    assert c._buf.tolist() == [-1.25, 5.0]
    assert Counter.x.__doc__ == "a float"
