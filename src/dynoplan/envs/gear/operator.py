"""Demonstrations as the paper records them: an operator chaining the paper's four options.

The paper's demonstrations come from a person choosing which option runs; the states
they visit are therefore the options' own. :class:`OptionOperator` is that person, with
a simple rule and sight of the human's hand:

- **pick** until the pick policy reports it is done (a failed pick starts again);
- then, every decision period (:data:`~dynoplan.envs.gear.state.DECISION_STEPS` steps),
  **cautious move** if the hand is within :data:`NEAR` of the tool, else **fast move**,
  until the running move reaches the pre-insertion offset;
- **insert** once there with the hand at least :data:`INSERT_CLEAR` away; if the hand
  comes within :data:`INSERT_NEAR` while inserting (or the insertion fails), back to the
  cautious move, which returns to the offset keeping its clearance;
- when the give-way option is registered
  (:mod:`~dynoplan.envs.gear.options.give_way_option`): once the gear is picked,
  **give way** when the hand comes within
  :data:`~dynoplan.envs.gear.options.give_way.GIVE_WAY_NEAR` of the left arm, until the
  give-way is done; then the moves go on (an interrupted insertion goes back to them).
  The pick is not interrupted: the pick's demonstrations, hence its Eq. 5 region, stay
  those of the four options (giving way during the pick changed which seeds the
  demonstrations succeeded on, and the pick's region then held 9 of the first 20
  evaluation starts instead of 20; ``docs/safety.md``).

Every step is labelled with the running option, so the safety regions and the goal
heuristic learned from these demonstrations describe where the real options go (the
scripted :class:`~dynoplan.envs.gear.expert.GearExpert` moves along its own paths, which
the planning options do not follow). It is a pipeline
:class:`~dynoplan.pipeline.collect.Demonstrator`: it chooses, the recorder
(:func:`~dynoplan.pipeline.collect.record_episode`) runs the chosen option of
:attr:`OptionOperator.specs`, started with the episode's generator; a failed pick or a
finished move chosen again is started again (a :class:`~dynoplan.pipeline.collect.Decision`
with ``restart``); it reads the success from the step's ``info`` (``observe``). Other
options registered after the paper's four are not demonstrated (the regions then leave
them out; their data comes from ``dynoplan gear collect``).
"""

from collections.abc import Mapping
from typing import Any

import numpy as np

from dynoplan.adapters.spec import OptionSpec
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.expert import CAUTIOUS_MOVE, FAST_MOVE, INSERT, PICK
from dynoplan.envs.gear.options.base import GearOptionPolicy, GearPolicyFactory
from dynoplan.envs.gear.options.catalog import GEAR_OPTIONS, PAPER_OPTIONS
from dynoplan.envs.gear.options.give_way import GIVE_WAY, GIVE_WAY_NEAR, left_arm_hand_distance
from dynoplan.envs.gear.state import DECISION_STEPS, PlannerState, tool_human_distance
from dynoplan.errors import DynoplanError
from dynoplan.options.termination import ConstantTermination
from dynoplan.pipeline.collect import Decision, Demonstrator
from dynoplan.types import FloatArray, Generator

NEAR = 0.45
"""Tool-hand distance (m) under which the operator moves cautiously (where the options'
``beta`` starts to rise, :func:`~dynoplan.envs.gear.state.proximity_beta`)."""
INSERT_NEAR = 0.25
"""Tool-hand distance (m) under which the operator stops inserting and backs off."""
INSERT_CLEAR = 0.3
"""Tool-hand distance (m) the operator waits for before inserting."""
MAX_PICK_ATTEMPTS = 3



class OptionOperator(Demonstrator):
    """Chains the option policies built by ``factories`` on ``env`` (module docstring).

    Its options are :attr:`specs` (the paper's four and, when it is registered, the
    give-way option), named as in the registry
    (:data:`~dynoplan.envs.gear.options.catalog.GEAR_OPTIONS`), whose names the labels
    index: record with ``option_names=gear_option_names()``. Record it with these specs:
    it reads their policies' status to decide.
    """

    def __init__(self, env: GearAssemblyEnv, factories: Mapping[str, GearPolicyFactory]
                 ) -> None:
        missing = [n for n in PAPER_OPTIONS if n not in factories]
        if missing:
            raise DynoplanError(f"the operator needs every option; missing {', '.join(missing)}")
        self.env = env
        self.policies: dict[int, GearOptionPolicy] = {
            label: factories[name](env) for label, name in enumerate(PAPER_OPTIONS)}
        self.give_way: int | None = None
        if GIVE_WAY.name in GEAR_OPTIONS.names() and GIVE_WAY.name in factories:
            self.give_way = GEAR_OPTIONS.index(GIVE_WAY.name)
            self.policies[self.give_way] = factories[GIVE_WAY.name](env)
        self.names = GEAR_OPTIONS.names()
        self.specs: list[OptionSpec] = [
            OptionSpec(self.names[label], policy, ConstantTermination(0.0))
            for label, policy in self.policies.items()]
        self.state_fn = PlannerState()
        self.info: dict[str, Any] = {}
        self._begin()

    def reset(self, observation: Any, rng: Generator) -> None:
        """A new episode: the pick first (the recorder starts the options with ``rng``)."""
        self._begin()

    def observe(self, info: dict[str, Any]) -> None:
        self.info = info

    def choose(self, observation: Any) -> Decision:
        """The option of the next step, started again (``restart``) when the rule starts
        the one that ran the step before."""
        obs = np.asarray(observation, dtype=np.float64)
        self.starts = False
        if self.running is None or self.steps_in_decision >= DECISION_STEPS \
                or self.policies[self.running].finished():
            self._decide(obs, self.info)
        assert self.running is not None
        self.steps_in_decision += 1
        return Decision(self.names[self.running], restart=self.starts)

    def _begin(self) -> None:
        self.running: int | None = None
        self.starts = False
        self.phase = "pick"
        self.pick_attempts = 0
        self.steps_in_decision = 0

    def _decide(self, obs: FloatArray, info: dict[str, Any]) -> None:
        """Choose the option for the next decision period (and start it if it changes)."""
        self.steps_in_decision = 0
        state = self.state_fn(obs)[None]
        distance = float(tool_human_distance(state)[0])
        current = None if self.running is None else self.policies[self.running]
        choice = self.running
        if self.give_way is not None and self.phase != "pick":
            if self.running == self.give_way:
                assert current is not None
                if not current.finished():
                    return
            elif float(left_arm_hand_distance(state)[0]) < GIVE_WAY_NEAR:
                self._start(self.give_way)
                return
        if self.phase == "pick":
            if current is None or current.status == "failed":
                if self.pick_attempts < MAX_PICK_ATTEMPTS:
                    self.pick_attempts += 1
                    self._start(PICK)
                return
            if current.status != "done":
                return
            self.phase = "move"
        if self.phase == "insert":
            assert current is not None
            if distance >= INSERT_NEAR and current.status == "running" \
                    and self.running == INSERT:
                return
            if bool(info.get("is_success", False)):
                return
            self.phase = "move"
            choice = CAUTIOUS_MOVE
            self._start(choice)
            return
        # move: fast or cautious to the offset, then insert
        arrived = current is not None and self.running in (FAST_MOVE, CAUTIOUS_MOVE) \
            and current.status == "done"
        if arrived and distance >= INSERT_CLEAR:
            self.phase = "insert"
            self._start(INSERT)
            return
        choice = CAUTIOUS_MOVE if distance < NEAR else FAST_MOVE
        if arrived and choice == CAUTIOUS_MOVE and self.running == CAUTIOUS_MOVE:
            return  # at the offset, waiting for the hand to clear
        if choice != self.running or (current is not None and current.finished()):
            self._start(choice)

    def _start(self, option: int) -> None:
        """Run ``option`` from this step on, started afresh (by the recorder)."""
        self.running = option
        self.starts = True


__all__ = ["INSERT_CLEAR", "INSERT_NEAR", "NEAR", "OptionOperator"]
