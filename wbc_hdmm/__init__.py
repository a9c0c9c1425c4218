"""The application: the ``wbc`` command (`wbc_hdmm.cli`) and the demo (`wbc_hdmm.demo`).

The top layer: it runs the scenarios, the estimators' evaluation and the benchmarks; no
library package imports it.
"""
