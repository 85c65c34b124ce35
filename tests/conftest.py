"""Taichi is initialised once for the whole suite: CPU, float64 (gradient checks need it).

float32 behaviour is tested in subprocesses (see tests that call `run_float32`)."""

import taichi_hair as th

th.init(arch="cpu", precision="float64")
