"""Butcher tableau of Cooper & Verner's explicit 8th-order, 11-stage Runge-Kutta method ("rk8").

Source: G. J. Cooper and J. H. Verner, "Some explicit Runge-Kutta methods of high order", SIAM J.
Numer. Anal. 9(3), 389-405 (1972): nodes 1/2 and (7 +- sqrt(21)) / 14, exact values in terms of
sqrt(21). ``tests/sim/test_integrators.py`` checks every order condition up to order 8 to
round-off. This is the one home of the tableau: :mod:`sim.integrators` re-exports it and
``tools/gen_rk8_step.py`` unrolls it into :mod:`sim.rk8_generated`; the module
imports nothing from ``sim`` so the generator runs even when the generated module is missing.
"""

import math

_S21 = math.sqrt(21.0)

#: Nodes c_i of the Cooper-Verner method (Cooper & Verner 1972, SIAM J. Numer. Anal. 9(3), 389-405:
#: their 11-stage 8th-order scheme); exact values in terms of sqrt(21).
RK8_C = (0.0, 1 / 2, 1 / 2, (7 + _S21) / 14, (7 + _S21) / 14, 1 / 2, (7 - _S21) / 14, (7 - _S21) / 14, 1 / 2,
         (7 + _S21) / 14, 1.0)

#: Coupling coefficients a_ij (row i lists a_i1 ... a_i,i-1) of the same method.
RK8_A = (
    (),
    (1 / 2,),
    (1 / 4, 1 / 4),
    (1 / 7, (-7 - 3 * _S21) / 98, (21 + 5 * _S21) / 49),
    ((11 + _S21) / 84, 0.0, (18 + 4 * _S21) / 63, (21 - _S21) / 252),
    ((5 + _S21) / 48, 0.0, (9 + _S21) / 36, (-231 + 14 * _S21) / 360, (63 - 7 * _S21) / 80),
    ((10 - _S21) / 42, 0.0, (-432 + 92 * _S21) / 315, (633 - 145 * _S21) / 90, (-504 + 115 * _S21) / 70,
     (63 - 13 * _S21) / 35),
    (1 / 14, 0.0, 0.0, 0.0, (14 - 3 * _S21) / 126, (13 - 3 * _S21) / 63, 1 / 9),
    (1 / 32, 0.0, 0.0, 0.0, (91 - 21 * _S21) / 576, 11 / 72, (-385 - 75 * _S21) / 1152, (63 + 13 * _S21) / 128),
    (1 / 14, 0.0, 0.0, 0.0, 1 / 9, (-733 - 147 * _S21) / 2205, (515 + 111 * _S21) / 504, (-51 - 11 * _S21) / 56,
     (132 + 28 * _S21) / 245),
    (0.0, 0.0, 0.0, 0.0, (-42 + 7 * _S21) / 18, (-18 + 28 * _S21) / 45, (-273 - 53 * _S21) / 72,
     (301 + 53 * _S21) / 72, (28 - 28 * _S21) / 45, (49 - 7 * _S21) / 18),
)

#: Weights b_i of the same method.
RK8_B = (1 / 20, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 49 / 180, 16 / 45, 49 / 180, 1 / 20)
