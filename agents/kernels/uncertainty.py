"""The uncertainty of the dynamical phase's consensus values m and J, compiled (docs/estimate-trust.md).

* :func:`spread_sd` -- the root-mean-square difference between the own consensus value of a channel pair
  (numerator / weight) and the neighbours' latest ones: what the averaging has not yet removed.
* :func:`uncertainties` -- one standard deviation of m and of J: the filter's sd of the own local value and
  that spread, in quadrature (NaN while the consensus weight is not positive).

Inputs: row ``b`` of agreement.py's flow-average bank ``F`` (the own values at ``F[b, X]``, neighbour slot
k's latest received x_j at ``F[b, FLOW + 2 D + k]``) and ``rx_order[b]``: the slots in the order their first
state arrived, -1 after the last (docs/fast-core-plan.md, section 1.6: with loss at the start that order is
not the id order, and it is the order of the spread's sum). The operations are those of the Python they
replace, in the same order (``** 2`` as :func:`agents.kernels.libm.pow_libm`, the quadrature as libm's hypot
through ``abs(complex)``), so the bits are the same (tests/test_uncertainty_kernels.py).
"""

from __future__ import annotations

import math

import numpy as np

from agents.kernels import jit, register_warm
from agents.kernels.agreement import FLOW, X, flow_average_bank
from agents.kernels.dynamic import CH_JN, CH_JW, CH_MN, CH_MW
from agents.kernels.libm import pow_libm


@jit
def spread_sd(b, own, F, rx_order, num, wch):  # noqa: ANN001, ANN201
    """sqrt(mean_j (v_j - own)^2) over the neighbours' values v_j = x_j[num] / x_j[wch] with x_j[wch] > 0
    and v_j not NaN, summed in first-heard order; 0.0 without such a value."""
    nx = FLOW + 2 * ((F.shape[1] - FLOW) // 3)
    acc = 0.0
    n = 0
    for m in range(rx_order.shape[1]):
        k = rx_order[b, m]
        if k < 0:
            break
        if F[b, nx + k, wch] > 0.0:
            v = F[b, nx + k, num] / F[b, nx + k, wch]
            if v == v:
                acc += pow_libm(v - own, 2.0)
                n += 1
    return math.sqrt(acc / n) if n else 0.0


@jit
def _sd(b, F, rx_order, num, wch, local_sd):  # noqa: ANN001, ANN202
    w = F[b, X, wch]
    if w <= 0.0:
        return math.nan
    s = spread_sd(b, F[b, X, num] / w, F, rx_order, num, wch)
    return abs(complex(local_sd if local_sd == local_sd else 0.0, s))


@jit
def uncertainties(b, F, rx_order, m_local_sd, j_local_sd):  # noqa: ANN001, ANN201
    """(sd of m, sd of J) of row b: the local sd (0 if NaN) and the spread to the neighbours in quadrature."""
    return (_sd(b, F, rx_order, CH_MN, CH_MW, m_local_sd), _sd(b, F, rx_order, CH_JN, CH_JW, j_local_sd))


@register_warm
def warm() -> None:
    F, _ = flow_average_bank(1, 1, CH_JW + 1)
    rx_order = np.full((1, 1), -1, np.int64)
    uncertainties(0, F, rx_order, 0.1, math.nan)
    spread_sd(0, 0.0, F, rx_order, CH_MN, CH_MW)
