"""The cost functionals a task may name (``cost:`` in the task file, ``--cost``).

covariant: ½ uᵀ M(q)⁻¹ u per unit time; torque: ½ uᵀ u. Kept apart from ``hoc_cli.problem`` so
that the task parser can validate the name without loading the numerical code.
"""

COSTS = ("covariant", "torque")
