"""The compiled kernel of `nlpcal.compiled` (numba): imported only where it runs."""

import numba
import numpy as np

_compile = numba.njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})


@_compile
def _product(out, a, b, m):
    """out[:m] = a[:m] * b[:m] (a loop of its own vectorises, where the same loop inline over
    rows of one array does not)."""
    for i in range(m):
        out[i] = a[i] * b[i]


@_compile
def add(sums, variables, weight, lvar, lpar, lpow, rvar, rpar, blocks, step):
    """sums[offset + (p - start) * prefix + q] += sum_i w_i l_p(i) r_q(i) for every block
    (start, stop, prefix, offset) of `blocks`, p in start:stop, q < prefix: the staircase of
    `nlpcal.monomials.MomentSet`, `step` samples at a time.

    variables : (n_variables, rows) C-contiguous. weight : (rows,) w_i, or empty for w_i = 1.
    lvar[v] : the row of `variables` of left variable v; lpar[p] for p >= 1 : (parent row,
        left variable), left row p being its parent times that variable, or (-2, -1) for a row
        built from powers, lpow[p, v] the power of left variable v. rvar, rpar : the same for
        the right rows. Left row 0 is w, right row 0 is 1.

    Each entry sums over the samples in a loop that LLVM vectorises, four left rows by two right
    ones at a time, so that each sample's values are loaded once for eight sums.
    """
    n = variables.shape[1]
    n_left, n_right = lpar.shape[0], rpar.shape[0]
    left = np.empty((n_left, step))
    right = np.empty((n_right, step))
    for first in range(0, n, step):
        m = min(step, n - first)
        last = first + m
        if weight.size:
            left[0, :m] = weight[first:last]
        else:
            left[0, :m] = 1.0
        right[0, :m] = 1.0
        for p in range(1, n_left):
            parent = lpar[p, 0]
            if parent >= 0:
                _product(left[p], left[parent], variables[lvar[lpar[p, 1]], first:last], m)
                continue
            left[p, :m] = left[0, :m]
            for k in range(lvar.shape[0]):
                for _ in range(lpow[p, k]):
                    _product(left[p], left[p], variables[lvar[k], first:last], m)
        for q in range(1, n_right):
            _product(right[q], right[rpar[q, 0]], variables[rvar[rpar[q, 1]], first:last], m)
        for b in range(blocks.shape[0]):
            start, stop, prefix, offset = blocks[b, 0], blocks[b, 1], blocks[b, 2], blocks[b, 3]
            _block_sums(sums, left, right, start, stop, prefix, offset, m)


@_compile
def _block_sums(sums, left, right, start, stop, prefix, offset, m):
    """The sums of one block of the staircase over the first m samples of the rows."""
    for p0 in range(start, stop, 4):
        p1 = min(p0 + 4, stop)
        for q0 in range(0, prefix, 2):
            q1 = min(q0 + 2, prefix)
            if p1 - p0 == 4 and q1 - q0 == 2:
                s00 = s01 = s10 = s11 = s20 = s21 = s30 = s31 = 0.0
                for i in range(m):
                    r0, r1 = right[q0, i], right[q0 + 1, i]
                    a0, a1 = left[p0, i], left[p0 + 1, i]
                    a2, a3 = left[p0 + 2, i], left[p0 + 3, i]
                    s00 += a0 * r0
                    s01 += a0 * r1
                    s10 += a1 * r0
                    s11 += a1 * r1
                    s20 += a2 * r0
                    s21 += a2 * r1
                    s30 += a3 * r0
                    s31 += a3 * r1
                row = offset + (p0 - start) * prefix + q0
                sums[row] += s00
                sums[row + 1] += s01
                sums[row + prefix] += s10
                sums[row + prefix + 1] += s11
                sums[row + 2 * prefix] += s20
                sums[row + 2 * prefix + 1] += s21
                sums[row + 3 * prefix] += s30
                sums[row + 3 * prefix + 1] += s31
                continue
            for p in range(p0, p1):
                for q in range(q0, q1):
                    s = 0.0
                    for i in range(m):
                        s += left[p, i] * right[q, i]
                    sums[offset + (p - start) * prefix + q] += s
