"""The decision drawn on a video's frames: which option runs, every option's score at the
last decision, a distance from the step's info."""

import numpy as np
import pytest

from dynoplan.control.controller import Decision, EpisodeTrace
from dynoplan.planning.option_planner import Plan
from dynoplan.reports.video import HOLD, caption_frames, draw_caption, step_captions


def plan(scores, admissible, chosen):
    n = len(scores)
    return Plan(("pick", "move", "insert")[:n], np.asarray(admissible, bool),
                np.asarray(scores, float), np.zeros(n), np.zeros((n, 1, 1)),
                np.zeros((n, 1), np.int64), chosen)


def trace():
    """Two steps of ``pick`` (move not admissible), one hold, one step of ``move``."""
    state = np.zeros(1)
    first = plan([0.5, np.nan, 0.1], [True, False, True], 0)
    hold = plan([np.nan, np.nan, np.nan], [False, False, False], None)
    last = plan([0.2, 0.7, -0.3], [True, True, True], 1)
    decisions = [Decision(0, 0, state, first, "pick", 2, "terminated", state, 0.01),
                 Decision(1, 2, state, hold, None, 1, "hold", state, 0.01),
                 Decision(2, 3, state, last, "move", 1, "episode_end", state, 0.01)]
    infos = [{"gap": d} for d in (0.9, 0.8, 0.7, 0.6)]
    return EpisodeTrace(decisions, success=True, env_steps=4, infos=infos)


def test_every_step_is_captioned_with_the_decision_that_ran_it():
    captions = step_captions(trace(), dt=0.05, distance_key="gap", distance_label="hand")
    assert [c.option for c in captions] == ["pick", "pick", HOLD, "move"]
    assert [round(c.time_s, 2) for c in captions] == [0.05, 0.1, 0.15, 0.2]
    assert captions[0].scores == (("pick", 0.5, True), ("move", None, False),
                                  ("insert", 0.1, False))
    assert all(score is None for _, score, _ in captions[2].scores)
    assert captions[3].distance == ("hand", 0.6)
    lines = captions[0].lines()
    assert lines[0] == "t  0.05 s   running: pick"
    assert lines[1] == "hand: 0.90 m"
    assert lines[3:] == ["> pick   +0.50", "  move      --", "  insert +0.10"]


def test_the_caption_is_drawn_top_left_and_the_frame_is_kept():
    frame = np.full((240, 320, 3), 200, np.uint8)
    caption = step_captions(trace(), dt=0.05)[0]
    drawn = draw_caption(frame, caption)
    assert drawn.shape == frame.shape and drawn.dtype == np.uint8
    assert (frame == 200).all()  # the input is not changed
    changed = np.argwhere((drawn != frame).any(axis=2))
    assert changed[:, 0].max() < 120 and changed[:, 1].max() < 240  # a box, top left
    yellow = (drawn[..., 0] > 200) & (drawn[..., 1] > 170) & (drawn[..., 2] < 120)
    assert yellow.sum() > 20  # the running option's line
    assert (drawn[200:, 250:] == 200).all()


def test_caption_frames_needs_one_frame_per_step():
    frames = [np.zeros((60, 80, 3), np.uint8) for _ in range(4)]
    caption_frames(frames, trace(), dt=0.05)
    assert len(frames) == 4 and all(f.any() for f in frames)
    with pytest.raises(ValueError, match="3 frames for 4 steps"):
        caption_frames(frames[:3], trace(), dt=0.05)
