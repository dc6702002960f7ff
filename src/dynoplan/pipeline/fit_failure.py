"""Where an option's runs end the episode in failure: ``P(fail | s)`` per option, from
the runs of the exploration episodes that terminated without success.

An option model in the sense of Sutton, Precup and Singh (1999) predicts where an option
ends; where its run ends the episode (a pole that falls, a lander that crashes), nothing
is left to do, whatever the goal heuristic says of the state it ended in. The planner
weighs each rollout's goal score by the option's chance not to fail from where it
starts (:attr:`~dynoplan.options.option.Option.failure`).
"""

from collections.abc import Sequence
from typing import Any

from dynoplan.control.controller import flat_state
from dynoplan.data.episodes import Episode
from dynoplan.models.outcome_initiation import OutcomeInitiation, fit_report_dict
from dynoplan.pipeline.collect import ObservationFn
from dynoplan.pipeline.fit_data import option_run_failures


def fit_failure(episodes: Sequence[Episode], option_names: Sequence[str], seed: int,
                state_fn: ObservationFn = flat_state,
                ) -> tuple[OutcomeInitiation | None, dict[str, Any]]:
    """Per option with runs, ``P(ok | s)``: whether a run that passed through ``s`` did not
    end its episode in failure (:func:`~dynoplan.pipeline.fit_data.option_run_failures`),
    a classifier fitted with every state weighing the same (so that it is a chance). An
    option none of whose runs failed gets ``always``; where no run failed at all (a task
    without failures, or demonstrations only) there is no model (``None``).

    Returns:
        The model (``None``: no run failed) and its report: per option its run states,
        the states of runs that did not fail (``positives``) and the classifier's kind.
    """
    runs = option_run_failures(episodes, option_names, state_fn)
    if not any(failed.any() for _, failed in runs.values()):
        return None, {}
    states = {name: s for name, (s, _) in runs.items() if len(s)}
    ok = {name: ~runs[name][1] for name in states}
    model, report = OutcomeInitiation.fit(states, ok, seed=seed, balanced=False)
    return model, fit_report_dict(report)


__all__ = ["fit_failure"]
