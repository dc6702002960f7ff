"""The fit steps of the gear's stages (:class:`~dynoplan.envs.gear.pipeline_stages.GearStages`'
``fit`` and ``after_fit``): the pipeline's fit on the gear's data, what is measured on
held-out trials (``metrics.json``), and the initiation learned from outcome runs.

- :mod:`.settings`: the gear's :class:`~dynoplan.pipeline.fit.FitSettings` and
  :class:`~.settings.GearMetricsSettings`;
- :mod:`.data`: datasets read, checked, cut into arrays and split;
- :mod:`.training`: :func:`~.training.train_gear_models`;
- :mod:`.metrics`: far-away states for the regions' report;
- :mod:`.outcomes`: the outcome runs and the initiation learned from them.

The demonstrations and option runs these fits read are recorded by
:mod:`dynoplan.envs.gear.demonstrations` and :mod:`dynoplan.envs.gear.option_runs`.

The models folder they write is :mod:`dynoplan.envs.gear.models_folder`'s (read by the
controllers too, which sit above this package: its stages run the gear's Task).
"""
