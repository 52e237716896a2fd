"""Pure computation for stl-gcs: scenarios, STL, dynamics, the planner, plan files.

No vehicle I/O happens here.  Modules (import them directly; this package imports nothing so
that ``planner.trajectory`` users do not pay for CasADi):

* :mod:`planner.scenario`: ``load_scenario(path, vehicles=N) -> Problem`` (YAML, for-each
  expansion of the spec over vehicles, groups and pairs), reading its sections with
  :mod:`planner.scenario.sections`, the spec with :mod:`planner.scenario.spec`, checking
  mistakes with :mod:`planner.scenario.checks`; the result types are in
  :mod:`planner.problem`, the regions (boxes, prisms, cylinders) in :mod:`planner.spec.regions`,
  a power line's regions from its poles (the ``line:`` section) in :mod:`planner.scenario.line`.
* :mod:`planner.spec.predicates`: the spec's functions ``inside``, ``outside``, ``dist``, ``alt``,
  ``x``, ``y``, ``z`` (numpy exact, CasADi smooth), ``build_registry(problem)``.
* :mod:`planner.optimize`: ``plan(problem) -> PlanResult`` (CasADi/IPOPT), built from
  :mod:`planner.solve.nlp` (the NLP and the solvers), :mod:`planner.solve.guess` (the initial guess),
  :mod:`planner.results` and :mod:`planner.checks` (dense limit checks, numpy only);
  ``docs/solver-notes.md`` records what each choice measured.
* :mod:`planner.spec.heading`: the heading the spec's ``face`` asks for, derived from a plan (a yaw
  schedule); :mod:`planner.spec.captures`: the windows in which a plan faces its targets (where a
  flight takes pictures).
* :mod:`planner.planfile`: ``save_plan``, ``load_plan`` (docs/scenario-format.md, "Plan files").
* :mod:`planner.stl`, :mod:`planner.dynamics`, :mod:`planner.trajectory`,
  :mod:`planner.frames`: the STL engine, motion models, trajectories and frames.

Error tree (each message names the file/field/position)::

    planner.errors.PlannerError             the root: bad input to the planner
      planner.errors.FileFieldError         a mistake in an input file (file, key path,
                                            problem; a ValueError)
        planner.scenario.sections.ScenarioError   ... in a scenario file
        planner.planfile.PlanFileError            ... in a plan file (missing, not JSON, ...)
      planner.stl.STLError                  STL engine errors (SpecError: syntax,
                                            line/column; EvaluationError: unknown signal, ...)
      planner.dynamics.DynamicsError        bad model parameters (a ValueError)
      planner.trajectory.TrajectoryError    bad segment data (a ValueError)
      planner.frames.FrameError             bad geodetic/frame input (a ValueError)
      planner.spec.regions.ShapeError            a shape that cannot be: a polygon whose edges cross, an
                                            empty height range (a ValueError; the scenario
                                            reader names the field)

A failed optimisation is not an error: ``plan`` returns ``PlanResult(success=False, ...)``.
"""
