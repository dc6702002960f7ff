"""The composition suite: DynoPlan against each task's demonstrator, on tasks from
packages dynoplan does not own, with one set of default settings for all
(``python -m benchmarks.suite``)."""
