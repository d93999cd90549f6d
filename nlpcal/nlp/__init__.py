"""Every CasADi graph of nlpcal, one module per paper, all built once through
`nlpcal.nlp.solver.problem` and listed in `nlpcal.nlp.solver.PROBLEMS`.

`blocks` and `objective`: the nine-parameter problems of Zhou et al. (2010) on the moments, and
`steps` the solve of one of them, checked and finished by Newton steps;
`orthogonality`: Wang et al. (2015); `temperature`: Liu et al. (2022); `compass`: Qiu et al.
(2017).
"""

from . import blocks, compass, objective, orthogonality, solver, steps, temperature

__all__ = ["blocks", "compass", "objective", "orthogonality", "solver", "steps", "temperature"]
