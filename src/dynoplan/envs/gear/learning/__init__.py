"""The gear's own fit steps around the pipeline's one fit, run by the gear's stages
(:class:`~dynoplan.envs.gear.pipeline_stages.GearStages`' ``fit`` and ``after_fit``):

- :mod:`.settings`: the gear's :class:`~dynoplan.pipeline.fit.FitSettings` and what is
  measured on held-out trials (:class:`~.settings.GearMetricsSettings`);
- :mod:`.data`: its datasets read and checked, cut into arrays;
- :mod:`.training`: :func:`~.training.train_gear_models`, the pipeline's
  :func:`~dynoplan.pipeline.fit.fit_models` on the gear's data, then the held-out
  measurements of ``metrics.json``;
- :mod:`.metrics`: far-away states for the regions' report;
- :mod:`.outcomes`: the outcome runs (the pipeline's
  :func:`~dynoplan.pipeline.collect.collect_option_runs`) and the initiation learned
  from them (:func:`~dynoplan.pipeline.fit.fit_initiation_from_outcomes`).

The demonstrations and option runs these fits read are recorded by
:mod:`dynoplan.envs.gear.demonstrations` and :mod:`dynoplan.envs.gear.option_runs`.

The models folder they write is the pipeline's one format
(:mod:`dynoplan.envs.gear.models_folder` reads it for the gear, and so do the
controllers, which sit above this package: its stages run the gear's Task).
"""
