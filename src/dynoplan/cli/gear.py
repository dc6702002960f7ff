"""``dynoplan gear ...``: the simulated gear assembly (expert runs, pictures, videos)."""

import os
from pathlib import Path

import typer

gear_app = typer.Typer(
    help="The simulated PR2 gear assembly: scripted expert, demonstrations, renders.",
    no_args_is_help=True,
)


@gear_app.command("expert")
def expert(
    episodes: int = typer.Option(100, help="Seeded episodes to run."),
    seed: int = typer.Option(0, help="Seed from which every episode's seed is derived."),
    out: Path = typer.Option(Path("results/gear-expert"), help="Output folder."),
    human: str | None = typer.Option(None, help="Force the human: away, cross or block."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Run the scripted expert; write OUT/summary.json (success, contacts, speed)."""
    from dynoplan.experiments.gear_expert import run_expert

    summary = run_expert(episodes, seed, out, progress=not quiet, human_mode=human)
    typer.echo(
        f"success {summary['success_rate']:.1%} ({summary['successes']}/{summary['episodes']}),"
        f" robot-human contacts {summary['contacts']}, min distance "
        f"{summary['min_human_distance']:.3f} m, env.step {summary['realtime_factor']:.1f}x "
        f"real time -> {out}/summary.json"
    )


@gear_app.command("demos")
def demos(
    n: int = typer.Option(10, "--n", help="Demonstrations to record (the paper: 10)."),
    seed: int = typer.Option(0, help="Seed from which every episode's seed is derived."),
    out: Path = typer.Option(Path("results/gear-demos"), help="Dataset folder to write."),
    human: str | None = typer.Option(None, help="Force the human: away, cross or block."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Record expert demonstrations with option labels and progress as a dataset."""
    from dynoplan.experiments.gear_demos import record_demos

    summary = record_demos(n, seed, out, progress=not quiet, human_mode=human)
    modes = ", ".join(f"{k} {v}" for k, v in summary["human_modes"].items())
    typer.echo(f"{summary['episodes']} demonstrations, {summary['steps']} steps, success "
               f"{summary['success_rate']:.0%}, human: {modes} -> {out}")


@gear_app.command("render")
def render(
    seed: int = typer.Option(0, help="Episode seed."),
    out: Path = typer.Option(Path("results/gear-render"), help="Output folder."),
    video: bool = typer.Option(True, "--video/--no-video", help="Also write episode.mp4."),
    human: str | None = typer.Option(None, help="Force the human: away, cross or block."),
) -> None:
    """Write OUT/scene.png and OUT/episode.mp4 of the expert's episode (offscreen)."""
    # Headless machines: MuJoCo picks its GL backend when first imported.
    os.environ.setdefault("MUJOCO_GL", "egl")
    from dynoplan.experiments.gear_expert import render_scene

    written = render_scene(out, seed=seed, video=video, human_mode=human)
    typer.echo(" ".join(str(p) for p in written.values()))
