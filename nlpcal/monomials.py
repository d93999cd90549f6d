"""Distinct weighted moments of a few per-sample variables, gathered by a staircase of products.

A moment here is m_e = sum_i w_i prod_v v_i^(e_v): a sample weight w_i times a monomial of the
variables v (the centred sample's coordinates, a, gamma, the auxiliary channels...), e its
exponent tuple. The groups of moments of `nlpcal.moments` need a fixed set of them (`MomentSet`);
any entry of their Gram matrices is one of them.

How they are gathered (`MomentSet.add`). The variables split into two kinds: the right ones R
(by default the first two coordinates of the sample, x and y) and the left ones (the rest).
Every needed monomial is a product l r of a left monomial l (times w) and a right one r, so
with the chunk's rows

    Lft[p] = w l_p,    Rgt[q] = r_q       (monomials as rows, samples as columns)

the sums are the entries of Lft Rgt^T, one matrix product over the chunk (BLAS). Only the
needed entries are computed: the right monomials are ordered by degree, so each left monomial
needs a prefix of them; the left ones are sorted by the length of that prefix and grouped into
a few blocks, each one product Lft[block] Rgt[:prefix]^T (the staircase, `_blocks`). For the
nine-parameter objective with a constant reference that is 25 left and 45 right rows, and 343
products per sample in five blocks for its 295 distinct moments, against 1 081 for the 46 x 46
Gram matrix of its features. Each row is built as an earlier row times one variable, rows
whose parents are consecutive in one element-wise product (`_runs`: 28 products for the 70
rows). Building the rows costs about as much as the products (an element-wise product streams
three rows through the cache, ROW_COST), so the plan weighs both.

A linear map (for instance a Gram matrix of features, or the moments in another frame) is a
matrix that multiplies the vector of moments; a Gram matrix is a selection of entries
(`MomentSet.indices`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache, cached_property
from itertools import combinations_with_replacement

import numpy as np

from . import compiled

#: Samples per step of `MomentSet.add` at most, and the values (rows of monomials times
#: samples) a step holds at most: 2.3 MB, so that they stay in a core's L2 cache between their
#: building and their product (70 rows x 4096 samples for the nine-parameter objective).
KERNEL_ROWS = 4096
KERNEL_VALUES = 140 * 4096
#: The right factors tried: x; x and y; x, y and z (variables 2, 3, 4, the sample's coordinates
#: in `nlpcal.moments.VARIABLES`; the others are as good by symmetry).
RIGHT_CHOICES = ((2,), (2, 3), (2, 3, 4))
#: Cost of one more matrix product per chunk, in products per sample (call overhead). [1]
BLOCK_COST = 24
#: Cost of building one row of monomials, in products per sample: an element-wise product
#: streams three rows through the cache, a matrix product's entry is one fused multiply-add of
#: a blocked kernel (measured with OpenBLAS on AVX-512 and AVX2 cores: about 0.5 ns against
#: 0.07 ns per sample). [1]
ROW_COST = 7


def monomials(max_degree: int, variables: int = 3):
    """Exponent tuples of `variables` variables of degree <= max_degree, by degree, and how to
    build each one: (parent index, variable), the monomial being its parent times the variable."""
    exps: list[tuple[int, ...]] = [(0,) * variables]
    recipe = [(-1, -1)]  # (parent index, variable): monomial = parent * d[:, variable]
    for degree in range(1, max_degree + 1):
        for combo in combinations_with_replacement(range(variables), degree):
            e = [0] * variables
            for v in combo:
                e[v] += 1
            parent = list(e)
            parent[combo[-1]] -= 1
            exps.append(tuple(e))
            recipe.append((exps.index(tuple(parent)), combo[-1]))
    return tuple(exps), tuple(recipe)


def parents(exps: list) -> list:
    """(parent index, variable) for each exponent tuple of `exps`, a parent being an earlier
    entry that differs by one power; (-1, -1) for the constant, (-2, -1) for a monomial whose
    parents all come later (built from the variables' powers)."""
    where = {e: i for i, e in enumerate(exps)}
    recipe = []
    for i, e in enumerate(exps):
        if not any(e):
            recipe.append((-1, -1))
            continue
        found = (-2, -1)
        for v in range(len(e) - 1, -1, -1):
            if e[v]:
                parent = e[:v] + (e[v] - 1,) + e[v + 1 :]
                if where.get(parent, i) < i:
                    found = (where[parent], v)
                    break
        recipe.append(found)
    return recipe


@dataclass(frozen=True, eq=False)
class MomentSet:
    """The moments m_e = sum_i w_i prod_v v_i^(e_v) for the exponent tuples `keys`.

    keys : exponent tuples over the variables, each once. right : the variables of the right
    factor. The rest is the plan of `add`, built by `moment_set`.
    """

    keys: tuple
    right: tuple
    left_vars: tuple
    left_recipe: tuple
    left_powers: tuple  # per left row built from powers: ((variable, power), ...)
    right_recipe: tuple
    blocks: tuple  # (first row, last row + 1, right prefix) per matrix product
    gather: np.ndarray  # position of each key in the concatenated block sums

    @property
    def left_runs(self) -> tuple:
        return _runs(self.left_recipe)

    @property
    def right_runs(self) -> tuple:
        return _runs(self.right_recipe)

    @property
    def size(self) -> int:
        return len(self.keys)

    @property
    def products(self) -> int:
        """Products per sample of the staircase."""
        return sum((stop - start) * prefix for start, stop, prefix in self.blocks)

    @property
    def cost(self) -> float:
        """Work per sample, in products: rows built, products and matrix products."""
        return self.rows * ROW_COST + self.products + len(self.blocks) * BLOCK_COST

    @property
    def rows(self) -> int:
        """Rows built per chunk (left and right monomials)."""
        return len(self.left_recipe) + len(self.right_recipe)

    def indices(self, keys) -> np.ndarray:
        """Positions of the exponent tuples `keys` among the moments (an index array of their
        shape minus the tuples' own axis)."""
        where = {k: i for i, k in enumerate(self.keys)}
        rows = np.asarray(keys, dtype=int)
        flat = [where[tuple(k)] for k in rows.reshape(-1, rows.shape[-1]).tolist()]
        return np.reshape(np.array(flat, dtype=np.intp), rows.shape[:-1])

    def empty(self) -> np.ndarray:
        """Zero block sums, to be filled by `add` and read by `values`: the blocks' matrices
        one after another, each by rows."""
        return np.zeros(self.products)

    def add(self, sums: np.ndarray, variables, weight=None, fast: bool = False) -> None:
        """Add the moments of a chunk of samples to `sums` (from `empty`): with the compiled
        kernel when `fast` (`nlpcal.compiled`, its pass's choice by `nlpcal.compiled.use`),
        else with numpy, KERNEL_ROWS samples at a time.

        variables : (n_variables, rows) the variables' values, one row each (features as rows,
            samples as columns). weight : None (w_i = 1) or (rows,) w_i.
        """
        if fast and compiled.add(sums, variables, weight, self.compiled_plan):
            return
        rows = variables.shape[1]
        step = max(1, min(rows, KERNEL_ROWS, KERNEL_VALUES // self.rows))
        totals = self._block_sums(sums)
        left = np.empty((len(self.left_recipe), step))
        right = np.empty((len(self.right_recipe), step))
        for start in range(0, rows, step):
            stop = min(start + step, rows)
            self._step(
                totals,
                variables[:, start:stop],
                None if weight is None else weight[start:stop],
                left[:, : stop - start],
                right[:, : stop - start],
            )

    def _step(self, sums, variables, weight, left, right) -> None:
        left[0] = 1.0 if weight is None else weight
        powers: dict = {}
        for start, stop, parent, variable in self.left_runs:
            if parent >= 0:  # rows start:stop, each its parent times the variable
                values = variables[self.left_vars[variable]]
                np.multiply(left[parent : parent + stop - start], values, out=left[start:stop])
                continue
            row = left[start]
            row[:] = left[0]
            for v, p in self.left_powers[start]:
                if (v, p) not in powers:
                    powers[v, p] = variables[self.left_vars[v]] ** p
                row *= powers[v, p]
        right[0] = 1.0
        for start, stop, parent, variable in self.right_runs:
            values = variables[self.right[variable]]
            np.multiply(right[parent : parent + stop - start], values, out=right[start:stop])
        for total, (start, stop, prefix) in zip(sums, self.blocks):
            total += left[start:stop] @ right[:prefix].T

    def _block_sums(self, sums: np.ndarray) -> list:
        """The blocks' matrices of the flat block sums `sums`, as views."""
        views, offset = [], 0
        for start, stop, prefix in self.blocks:
            size = (stop - start) * prefix
            views.append(sums[offset : offset + size].reshape(stop - start, prefix))
            offset += size
        return views

    @cached_property
    def compiled_plan(self) -> compiled.KernelPlan:
        """The plan as the arrays of the compiled kernel (`nlpcal.compiled.add`)."""
        left_powers = np.zeros((len(self.left_recipe), len(self.left_vars)), dtype=np.int64)
        for row, powers in enumerate(self.left_powers):
            for variable, power in powers:
                left_powers[row, variable] = power
        sizes = [(stop - start) * prefix for start, stop, prefix in self.blocks]
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        return compiled.KernelPlan(
            np.array(self.left_vars, dtype=np.int64),
            np.array(self.left_recipe, dtype=np.int64),
            left_powers,
            np.array(self.right, dtype=np.int64),
            np.array(self.right_recipe, dtype=np.int64),
            np.column_stack([np.array(self.blocks, dtype=np.int64), offsets.astype(np.int64)]),
        )

    def values(self, sums: np.ndarray) -> np.ndarray:
        """The moments (in the order of `keys`) from the block sums."""
        return sums[self.gather]


def moment_set(keys, right=None) -> MomentSet:
    """The plan of `MomentSet.add` for the exponent tuples `keys` (duplicates dropped, order
    kept), with the variables `right` as the right factor (None: of RIGHT_CHOICES, the one
    whose plan costs least, rows built and products, `cost`)."""
    rows = np.asarray(keys, dtype=int)
    _, first = np.unique(rows, axis=0, return_index=True)
    keys = tuple(map(tuple, rows[np.sort(first)].tolist()))
    if right is None:
        plans = [moment_set(keys, choice) for choice in RIGHT_CHOICES]
        return min(plans, key=lambda plan: plan.cost)
    nvars = len(keys[0])
    left_vars = tuple(v for v in range(nvars) if v not in right)
    max_right = max(sum(k[v] for v in right) for k in keys)
    right_exps, right_recipe = monomials(max_right, len(right))
    right_at = {e: i for i, e in enumerate(right_exps)}
    prefix: dict = {}  # left exponents -> columns it needs
    for k in keys:
        lk = tuple(k[v] for v in left_vars)
        column = right_at[tuple(k[v] for v in right)]
        prefix[lk] = max(prefix.get(lk, 0), column + 1)
    # Longest prefix first; among equals, lower degree first (parents before children). Row 0
    # is w itself, built whether or not a moment needs it.
    zero = (0,) * len(left_vars)
    order = sorted(prefix, key=lambda e: (-prefix[e], sum(e), e))
    skip = int(zero not in prefix)
    if zero in order:
        order.remove(zero)
    order.insert(0, zero)
    recipe = parents(order)
    powers = tuple(
        tuple((v, p) for v, p in enumerate(e) if p) if r[0] == -2 else ()
        for e, r in zip(order, recipe)
    )
    blocks = [
        (start + skip, stop + skip, width)
        for start, stop, width in _blocks([prefix[e] for e in order[skip:]])
    ]
    # The block and the entry of each key.
    position = {}
    offset = 0
    for start, stop, width in blocks:
        for row in range(start, stop):
            for column in range(width):
                position[order[row], column] = offset + (row - start) * width + column
        offset += (stop - start) * width
    gather = np.array(
        [
            position[tuple(k[v] for v in left_vars), right_at[tuple(k[v] for v in right)]]
            for k in keys
        ],
        dtype=np.intp,
    )
    return MomentSet(
        keys, tuple(right), left_vars, tuple(recipe), powers, right_recipe, tuple(blocks), gather
    )


@cache
def _runs(recipe: tuple) -> tuple:
    """The rows after the first as runs (start, stop, parent start, variable): rows start:stop
    are rows parent:parent + stop - start, all built before start, times one variable (one
    element-wise product each); a row without an earlier parent is a run of its own with
    parent -2."""
    runs: list = []
    for index in range(1, len(recipe)):
        parent, variable = recipe[index]
        if runs and parent >= 0:
            start, stop, first, var = runs[-1]
            if (
                stop == index
                and first >= 0
                and var == variable
                and parent == first + stop - start
                and first + stop - start < start
            ):
                runs[-1] = (start, index + 1, first, var)
                continue
        runs.append((index, index + 1, parent, variable))
    return tuple(runs)


def _blocks(prefixes: list) -> list:
    """Contiguous groups of rows (prefixes non-increasing, except row 0) with the least
    products plus BLOCK_COST per group: (start, stop, width) each."""
    n = len(prefixes)
    best = [0.0] + [float("inf")] * n
    cut = [0] * (n + 1)
    for stop in range(1, n + 1):
        width = 0
        for start in range(stop - 1, -1, -1):
            width = max(width, prefixes[start])
            cost = best[start] + (stop - start) * width + BLOCK_COST
            if cost < best[stop]:
                best[stop], cut[stop] = cost, start
    blocks = []
    stop = n
    while stop:
        start = cut[stop]
        blocks.append((start, stop, max(prefixes[start:stop])))
        stop = start
    return blocks[::-1]
