"""How DynoPlan plans and how every controller runs an episode: :class:`ControllerSettings`,
the settings a task's runners are built with (:meth:`~dynoplan.pipeline.task.Task.make_runner`)."""

from dataclasses import dataclass
from typing import Any

from dynoplan.errors import DynoplanError
from dynoplan.limits import DEPTH_MAX


@dataclass(frozen=True)
class ControllerSettings:
    """How DynoPlan plans and how every controller runs an episode.

    Attributes:
        horizon: ``n`` of Eq. 1, in model steps (``stride`` environment steps each).
        samples: Monte-Carlo rollouts per option (per option sequence at ``depth`` > 1).
        depth: options per imagined sequence of DynoPlan's planner (1: the paper's Eq. 1,
            :class:`~dynoplan.planning.OptionPlanner`; more: the look-ahead of
            :class:`~dynoplan.planning.SequencePlanner`).
        risk: ``k`` in ``E[G] - k * std[G]`` (0: the paper's expectation).
        replan_every: plan again after this many environment steps (``None``: only
            when the option stops).
        margin: score advantage needed to replace a running option at a replan.
        commit: at a replan, the running option goes on while its own score has not
            fallen by more than this below the score it was chosen with, whatever the
            others score (:class:`~dynoplan.control.Controller`; ``None``: the margin
            rule alone decides).
        max_decisions: planning steps before an episode is given up.
        max_option_steps: environment steps one option may run between decisions.
        hold_action: action when no option is admissible (``None``: the task's own;
            a Gymnasium task's is :func:`~dynoplan.pipeline.evaluate.neutral_action`, the
            zero action of a ``Box`` action space); a tuple is the action as an array (a
            tuple keeps the settings hashable, as worker jobs need).
        hold: hold when no option is admissible; ``False``: end the episode there (and
            so with no hold action at all, e.g. a discrete action space).
        oracle_horizon: decisions a simulator oracle simulates per rollout (tasks whose
            environment can be simulated from a state; it pays real simulation time, so
            it may be shorter than ``horizon``).
        oracle_samples: simulated rollouts per option of the oracle.
        dynamics_noise: std of Gaussian noise added to every learned prediction of
            DynoPlan's planner (a fault; 0 for none).
        epistemic: weight of the dynamics ensemble's disagreement in the planner's score
            (:class:`~dynoplan.planning.OptionPlanner`; 0: the paper's expectation).
        risk_level: ``epsilon`` of a chance-constrained Eq. 1: the largest share of an
            option's rollouts with an unsafe step (for planners given a safety
            constraint).
        end_inside: the planner's rollouts that leave an option's continuation set end
            at their last state inside it (:class:`~dynoplan.planning.OptionPlanner`).
        no_effect_tolerance: an option that terminates with no state coordinate moved
            more than this is not started again there
            (:class:`~dynoplan.control.Controller`; ``None``: see ``no_effect_share``).
        no_effect_share: without ``no_effect_tolerance``, the tolerance of each state
            coordinate is this share of its spread over the fitted data
            (``state_scale`` of :func:`~dynoplan.pipeline.evaluate.make_controller`;
            ``None``: no such rule).
        loop_share: where the state comes back to a state at which an earlier decision
            of the episode was made, every coordinate within this share of its spread
            over the fitted data, the options started there may not start again while
            the state stays there (:class:`~dynoplan.control.Controller`'s
            ``loop_tolerance``; ``None``: no such rule).
        loop_progress: a loop is judged by the goal heuristic: the options whose runs
            in it lowered the goal heuristic undid the others' progress and may not
            start anywhere until it passes the loop's highest value
            (:class:`~dynoplan.control.Controller`'s ``progress``); ``False``: the
            options started where the loop began may not start there again.
        fallback_own_sets: where no option may start under its learned initiation set
            (region, outcomes), the options whose own initiation sets hold may (the
            chooser picks among them as always; the options' ``fallback``); where the
            controller can hold, DynoPlan starts one there only if it scores at least the
            goal heuristic at the present state (``fallback_must_gain``); ``False``: the
            controller holds (``hold_action``) or ends the episode there.
        fallback_goes_on: with ``fallback_own_sets``, an option that leaves its
            continuation set where no option may start under its learned initiation set
            goes on while its own set holds, as one started there would
            (:class:`~dynoplan.control.Controller`); ``False``: it stops there, and the
            controller chooses again under the fallback sets.
        fallback_must_gain: with ``fallback_own_sets``, where the controller can hold,
            DynoPlan starts an option under its own set only if it scores at least the
            goal heuristic at the present state, and holds otherwise; ``False``: it starts
            the best-scoring one.
        fallback_without_gain: with ``fallback_own_sets``, where options may start under
            their learned sets but DynoPlan predicts none of them to score the goal
            heuristic at the present state, the demonstrated options whose own sets hold
            there are scored too, and the best of them runs if it scores at least that and more
            than the best learned choice (the planner's ``widen_without_gain``); it goes
            on while its own set holds (depth 1 only). ``False``: the learned sets alone
            decide there.
        regions_without_gain: where options may start under their learned sets but
            DynoPlan predicts none of them to score the goal heuristic at the present
            state, the admissible option whose Eq. 5 region gives the state the highest
            likelihood (the demonstrations' choice there, ``Option.likelihood``) runs
            instead of the best-scoring one (the planner's ``regions_without_gain``; the
            default since the eighteenth round of the composition suite; the sequence
            planner, depth > 1, has no such rule). ``False``: the best-scoring one runs.
        stall_progress: where DynoPlan held, the hold changed nothing and it would hold
            again (``fallback_must_gain``) at a state whose goal heuristic is below this,
            it starts the best-scoring option instead (:class:`~dynoplan.control.Controller`;
            ``None``: it holds).
        stall_forgets: where DynoPlan held in place below ``stall_progress`` and no
            option may start at all, the options forget where their runs ended without
            effect (the no-effect and loop rules' marks) and DynoPlan chooses again (the
            controller's ``stall_goal``; the default since the twenty-second round of
            the composition suite; ``False``: it holds while the state stays there).
        score_failures: DynoPlan weighs each rollout's goal score by its option's chance
            not to end the episode in failure from where it starts (the options'
            ``failure``, fitted where exploration runs failed; ``False``: a failing run is
            scored by where it ends, as any other).
        start_where_done: an option may start where its termination is certain
            (``False``, the default: it may not, :meth:`~dynoplan.options.Option.done_at`;
            every controller but the demonstrator follows the rule).
    """

    horizon: int = 20
    samples: int = 32
    depth: int = 1
    risk: float = 0.0
    replan_every: int | None = 10
    margin: float = 0.0
    commit: float | None = None
    max_decisions: int = 1000
    max_option_steps: int = 1000
    hold_action: Any = None
    hold: bool = True
    oracle_horizon: int = 10
    oracle_samples: int = 1
    dynamics_noise: float = 0.0
    epistemic: float = 0.0
    risk_level: float = 0.05
    end_inside: bool = False
    no_effect_tolerance: float | None = None
    no_effect_share: float | None = 0.01
    loop_share: float | None = 0.05
    loop_progress: bool = False
    start_where_done: bool = False
    fallback_own_sets: bool = True
    fallback_goes_on: bool = False
    fallback_must_gain: bool = True
    fallback_without_gain: bool = False
    regions_without_gain: bool = True
    stall_progress: float | None = 0.5
    stall_forgets: bool = True
    score_failures: bool = True

    def validate(self) -> None:
        if self.horizon < 1 or self.samples < 1:
            raise DynoplanError(
                f"horizon and samples must be >= 1, got {self.horizon} and {self.samples}")
        if not 1 <= self.depth <= DEPTH_MAX:
            raise DynoplanError(f"depth must be in [1, {DEPTH_MAX}], got {self.depth}")
        if self.fallback_without_gain and self.depth != 1:
            raise DynoplanError("fallback_without_gain is a rule of the depth-1 planner; "
                                f"got depth {self.depth}")
        if self.oracle_horizon < 1 or self.oracle_samples < 1:
            raise DynoplanError(
                f"oracle_horizon and oracle_samples must be >= 1, got {self.oracle_horizon} "
                f"and {self.oracle_samples}")
        if not self.dynamics_noise >= 0.0:
            raise DynoplanError(f"dynamics_noise must be >= 0, got {self.dynamics_noise}")
        if not self.epistemic >= 0.0:
            raise DynoplanError(f"epistemic must be >= 0, got {self.epistemic}")
        if not 0.0 <= self.risk_level <= 1.0:
            raise DynoplanError(f"risk_level must be in [0, 1], got {self.risk_level}")
        if self.replan_every is not None and self.replan_every < 1:
            raise DynoplanError(f"replan_every must be >= 1 or None, got {self.replan_every}")
        if self.commit is not None and not self.commit >= 0.0:
            raise DynoplanError(f"commit must be >= 0 or None, got {self.commit}")
        if self.max_decisions < 1 or self.max_option_steps < 1:
            raise DynoplanError("max_decisions and max_option_steps must be >= 1")
        if self.no_effect_share is not None and not self.no_effect_share >= 0.0:
            raise DynoplanError(
                f"no_effect_share must be >= 0 or None, got {self.no_effect_share}")
        if self.loop_share is not None and not self.loop_share >= 0.0:
            raise DynoplanError(f"loop_share must be >= 0 or None, got {self.loop_share}")
        if self.stall_progress is not None and not self.stall_progress >= 0.0:
            raise DynoplanError(
                f"stall_progress must be >= 0 or None, got {self.stall_progress}")
        if self.no_effect_tolerance is not None and not self.no_effect_tolerance >= 0.0:
            raise DynoplanError(
                f"no_effect_tolerance must be >= 0 or None, got {self.no_effect_tolerance}")


__all__ = ["ControllerSettings"]
