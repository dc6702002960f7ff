"""The gear's learned models: the pipeline's fit on the gear's data, and what is measured
on held-out trials (``metrics.json``).

- :mod:`.settings`: the gear's :class:`~dynoplan.pipeline.fit.FitSettings` and
  :class:`~.settings.GearMetricsSettings`;
- :mod:`.data`: datasets read, checked, cut into arrays and split;
- :mod:`.training`: :func:`~.training.train_gear_models`;
- :mod:`.metrics`: far-away states for the regions' report.

The models folder they write is :mod:`dynoplan.envs.gear.models_folder`'s (read by the
controllers too, which sit above this package: its stages run the gear's Task).
"""
