"""Benchmarks that print JSON; each is a module ``_<name>.py`` with ``add_arguments(parser)`` and
``run(args) -> dict``, dispatched by ``openemt bench <name>``.

Solver benchmarks:

- ``_noise``: Teixeira Silva et al. 2017 noise protocol for the pose solvers next to the Cramer-Rao bound.
- ``_speed``: poses per second on one core for each solver vs a per-pose scipy baseline.
"""

__all__: list[str] = []
