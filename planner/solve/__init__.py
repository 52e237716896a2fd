"""The planner's solving machinery behind :func:`planner.optimize.plan`: the initial guess,
the combinatorial stage (with :mod:`planner.milp`), the NLP and its solvers, the refinements
and the exact check of a plan.  Import the modules directly."""
