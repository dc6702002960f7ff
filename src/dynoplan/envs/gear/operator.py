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
the planning options do not follow). It has the expert's interface: ``reset()`` and
``act(observation, info) -> ExpertAction``. Other options registered after the paper's
four are not demonstrated (the regions then leave them out; their data comes from
``dynoplan gear collect``).
"""

from collections.abc import Mapping
from typing import Any

import numpy as np

from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.expert import CAUTIOUS_MOVE, FAST_MOVE, INSERT, PICK, ExpertAction
from dynoplan.envs.gear.options.base import GearOptionPolicy, GearPolicyFactory
from dynoplan.envs.gear.options.catalog import GEAR_OPTIONS, PAPER_OPTIONS
from dynoplan.envs.gear.options.give_way import GIVE_WAY, GIVE_WAY_NEAR, left_arm_hand_distance
from dynoplan.envs.gear.options.motion import reseed_ompl
from dynoplan.envs.gear.state import DECISION_STEPS, PlannerState, tool_human_distance
from dynoplan.errors import DynoplanError
from dynoplan.types import FloatArray

NEAR = 0.45
"""Tool-hand distance (m) under which the operator moves cautiously (where the options'
``beta`` starts to rise, :func:`~dynoplan.envs.gear.state.proximity_beta`)."""
INSERT_NEAR = 0.25
"""Tool-hand distance (m) under which the operator stops inserting and backs off."""
INSERT_CLEAR = 0.3
"""Tool-hand distance (m) the operator waits for before inserting."""
MAX_PICK_ATTEMPTS = 3



class OptionOperator:
    """Chains the option policies built by ``factories`` on ``env`` (module docstring);
    labels are the options' indices in the registry
    (:data:`~dynoplan.envs.gear.options.catalog.GEAR_OPTIONS`): the paper's four are
    0..3, the give-way option its own label when it is registered."""

    def __init__(self, env: GearAssemblyEnv, factories: Mapping[str, GearPolicyFactory],
                 seed: int = 0) -> None:
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
        self.state_fn = PlannerState()
        self.rng = np.random.default_rng(seed)
        self.reset()

    def reseed(self, seed: int) -> None:
        """Make the next episode depend on ``seed`` alone, not on the episodes before it
        in this process: OMPL (the moves' and the pick's plans,
        :func:`~dynoplan.envs.gear.options.motion.reseed_ompl`) and the generator handed to
        the options are seeded from it. Call it before an independent episode."""
        reseed_ompl(seed)
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        self.running: int | None = None
        self.phase = "pick"
        self.pick_attempts = 0
        self.steps_in_decision = 0

    def act(self, observation: FloatArray, info: dict[str, Any]) -> ExpertAction:
        """The next action (13,) and the running option's index as its label."""
        obs = np.asarray(observation, dtype=np.float64)
        if self.running is None or self.steps_in_decision >= DECISION_STEPS \
                or self.policies[self.running].finished():
            self._decide(obs, info)
        assert self.running is not None
        self.steps_in_decision += 1
        action = self.policies[self.running].act(obs)
        return ExpertAction(action=action, option=self.running, step=self.phase)

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
                self._start(self.give_way, obs)
                return
        if self.phase == "pick":
            if current is None or current.status == "failed":
                if self.pick_attempts < MAX_PICK_ATTEMPTS:
                    self.pick_attempts += 1
                    self._start(PICK, obs)
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
            self._start(choice, obs)
            return
        # move: fast or cautious to the offset, then insert
        arrived = current is not None and self.running in (FAST_MOVE, CAUTIOUS_MOVE) \
            and current.status == "done"
        if arrived and distance >= INSERT_CLEAR:
            self.phase = "insert"
            self._start(INSERT, obs)
            return
        choice = CAUTIOUS_MOVE if distance < NEAR else FAST_MOVE
        if arrived and choice == CAUTIOUS_MOVE and self.running == CAUTIOUS_MOVE:
            return  # at the offset, waiting for the hand to clear
        if choice != self.running or (current is not None and current.finished()):
            self._start(choice, obs)

    def _start(self, option: int, obs: FloatArray) -> None:
        self.running = option
        self.policies[option].reset(obs, self.rng)


__all__ = ["INSERT_CLEAR", "INSERT_NEAR", "NEAR", "OptionOperator"]
