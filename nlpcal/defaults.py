"""Defaults that the library and the command line share, in one module that imports nothing, so
that `nlpcal --help` can show them without loading the solvers."""

#: Most cycles of the staged method, in `calibrate`, `compare` and `batch calibrate`: every real
#: log tried needs fewer than 200 (`docs/real-data.md`). [1]
CYCLES_DEFAULT = 500
#: The staged cycle stops when a cycle lowers the objective by less than this fraction. [1]
RTOL_DEFAULT = 1e-9
