"""The application: the ``wbc`` command (`wbc_hdmm.cli`) and the demo (`wbc_hdmm.demo`).

The top layer: it runs the scenarios, the estimators' evaluation and the benchmarks; no
library package imports it.
"""

import os

# One BLAS thread, set before numpy loads: the controller's per-tick products are small
# (a 220 x 108 by 108 x 108 product in the MPC's solve), a BLAS that spreads them over
# threads gains nothing on them and, with another process on the other core, turned the
# MPC's 0.5 ms solve into 5-10 ms; the sweep's workers run so already. An explicit
# setting in the environment wins.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
