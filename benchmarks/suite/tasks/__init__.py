"""The composition suite's tasks: one module per task, written from the user guide as a
user would, on environments from packages dynoplan does not own.

A task module defines (the contract :mod:`benchmarks.suite.registry` reads):

- ``ENV_ID``: a Gymnasium id, registered by the module itself when it needs its own
  wrapper or step limit (``gymnasium.register`` at import, guarded by
  ``if ENV_ID not in gymnasium.registry``);
- ``make_options() -> list[OptionSpec]``: the options (plain functions of the planner
  state, :func:`dynoplan.adapters.option_spec`), at least one a distractor the
  demonstrator never uses;
- ``make_demonstrator() -> Demonstrator``: a scripted chain of the options;
- ``success(observation, info) -> bool`` or ``success = None`` (the environment's own
  ``info["is_success"]``/``terminated``);
- ``state_fn(observation) -> (d,)`` or ``state_fn = None`` (a ``Box`` observation as
  it is);
- ``disturb(env) -> env``: the task's disturbance, a Gymnasium wrapper seeded from the
  seed of ``reset``, and ``DISTURBANCE``: what it does, in one line.
"""
