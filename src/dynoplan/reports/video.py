"""MP4 videos of rendered episodes (imageio with the ffmpeg its wheel ships), with the
controller's decision drawn on every frame.

A captioned frame shows, top left: the episode time and the option that runs (or
``hold``), every option's score at the last decision (the chosen one marked ``>``, an
option that was not admissible ``-``), and optionally a distance the environment
reports in its ``info`` (the gear: the robot's distance to the human's hand). Captions
are drawn after the episode, from its trace, so they change no result.
"""

import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from dynoplan.control.controller import EpisodeTrace
from dynoplan.io import write_with

HOLD = "hold"
"""What a caption shows as running when no option was admissible."""


def write_mp4(path: Path, frames: Sequence[npt.NDArray[np.uint8]], fps: int) -> Path:
    """Write ``frames`` (H, W, 3) ``uint8`` as an H.264 MP4 at ``fps``, atomically."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("no frames to write")
    write_with(path, lambda p: imageio.mimwrite(p, list(frames), fps=fps,
                                                codec="libx264", quality=7))
    return path


@dataclass(frozen=True)
class Caption:
    """What one frame shows of the decision.

    Attributes:
        time_s: episode time after the frame's step.
        option: the option that ran the step, or :data:`HOLD`.
        scores: per option ``(name, score at the last decision or None when it was not
            admissible or not scored, whether it was chosen)``.
        distance: ``(label, metres)`` or ``None``.
    """

    time_s: float
    option: str
    scores: tuple[tuple[str, float | None, bool], ...]
    distance: tuple[str, float] | None = None

    def lines(self) -> list[str]:
        """The caption's text, one string per line."""
        out = [f"t {self.time_s:5.2f} s   running: {self.option}"]
        if self.distance is not None:
            out.append(f"{self.distance[0]}: {self.distance[1]:.2f} m")
        out.append("scores at the last decision:")
        width = max((len(name) for name, _, _ in self.scores), default=0)
        for name, score, chosen in self.scores:
            shown = f"{'--':>5}" if score is None else f"{score:+.2f}"
            out.append(f"{'>' if chosen else ' '} {name:<{width}} {shown}")
        return out


def step_captions(trace: EpisodeTrace, dt: float, distance_key: str | None = None,
                  distance_label: str = "distance") -> list[Caption]:
    """One :class:`Caption` per environment step of ``trace`` (``trace.env_steps``), in
    order: step ``k`` is shown with the decision that ran it.

    Args:
        dt: seconds per environment step.
        distance_key: a key of every step's ``info`` (the trace recorded with
            ``record_infos``) holding a distance in metres to show, under
            ``distance_label``; ``None``: no distance.
    """
    captions: list[Caption | None] = [None] * trace.env_steps
    for d in trace.decisions:
        plan = d.plan
        scores = tuple(
            (name, float(plan.scores[i]) if bool(plan.admissible[i])
             and np.isfinite(plan.scores[i]) else None, d.option == name)
            for i, name in enumerate(plan.option_names))
        first = d.env_step
        for k in range(first, min(first + d.steps, trace.env_steps)):
            distance = None
            if distance_key is not None and k < len(trace.infos) and \
                    distance_key in trace.infos[k]:
                distance = (distance_label, float(trace.infos[k][distance_key]))
            captions[k] = Caption((k + 1) * dt, d.option or HOLD, scores, distance)
    missing = [k for k, c in enumerate(captions) if c is None]
    if missing:
        raise ValueError(f"steps {missing[:3]} of the trace belong to no decision")
    return [c for c in captions if c is not None]


def caption_frames(frames: list[Any], trace: EpisodeTrace, dt: float,
                   distance_key: str | None = None, distance_label: str = "distance") -> None:
    """Draw :func:`step_captions` onto ``frames`` in place: one frame per step of
    ``trace``, each an (H, W, 3) ``uint8`` RGB array rendered after its step."""
    captions = step_captions(trace, dt, distance_key, distance_label)
    if len(captions) != len(frames):
        raise ValueError(f"{len(frames)} frames for {len(captions)} steps")
    frames[:] = [draw_caption(f, c) for f, c in zip(frames, captions, strict=True)]


def draw_caption(frame: npt.NDArray[np.uint8], caption: Caption) -> npt.NDArray[np.uint8]:
    """``frame`` with ``caption`` drawn top left, white on a translucent dark box (the
    running option's line in yellow); a new array, ``frame`` is not changed."""
    from PIL import Image, ImageDraw

    image = Image.fromarray(np.asarray(frame, dtype=np.uint8)).convert("RGBA")
    font = _font(max(11, image.height // 34))
    lines = caption.lines()
    pad, step = 6, font.size + 3
    width = max(int(font.getlength(line)) for line in lines) + 2 * pad
    box = Image.new("RGBA", image.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(box)
    draw.rectangle((4, 4, 4 + width, 4 + 2 * pad + step * len(lines)), fill=(0, 0, 0, 160))
    for i, line in enumerate(lines):
        colour = (255, 220, 60, 255) if i == 0 or line.startswith(">") else (255, 255, 255, 255)
        draw.text((4 + pad, 4 + pad + i * step), line, font=font, fill=colour)
    out: npt.NDArray[np.uint8] = np.asarray(Image.alpha_composite(image, box).convert("RGB"))
    return out


@lru_cache(maxsize=4)
def _font(size: int) -> Any:
    """A monospaced TrueType font (the DejaVu Sans Mono matplotlib ships)."""
    from matplotlib import font_manager
    from PIL import ImageFont

    return ImageFont.truetype(font_manager.findfont("DejaVu Sans Mono"), size)


__all__ = ["HOLD", "Caption", "caption_frames", "draw_caption", "step_captions", "write_mp4"]


def video_clip(frames: Sequence[Any], success: bool, options: Sequence[str]) -> dict[str, Any]:
    """An episode's ``frames`` (RGB arrays, 20 per second) as ``{"mp4": bytes of the H.264
    file, "success", "options"}`` (the options it ran, consecutive repeats collapsed)."""
    with tempfile.TemporaryDirectory() as tmp:
        mp4 = write_mp4(Path(tmp) / "episode.mp4", frames, fps=20).read_bytes()
    return {"mp4": mp4, "success": success, "options": _runs(options)}


def _runs(options: Sequence[str]) -> list[str]:
    """Consecutive repeats collapsed: ``[a, a, b, a] -> [a, b, a]``."""
    return [o for k, o in enumerate(options) if k == 0 or options[k - 1] != o]
