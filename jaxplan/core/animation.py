"""Writing matplotlib animations to files, for every system's viewer."""
from __future__ import annotations


def save_animation(fig, draw, n: int, path, *, fps: int, dpi: int) -> None:
    """Render ``draw(i)`` for ``i < n`` into ``path`` (.gif with Pillow, else ffmpeg) and close ``fig``.

    An interrupt (Ctrl-C, SIGTERM) stays an interrupt: matplotlib's writer finishes the file in a
    ``finally`` clause, which fails when no frame was written yet (an ``IndexError`` in place of the
    interrupt, so the run would be marked failed instead of interrupted)."""
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib import animation  # noqa: PLC0415

    anim = animation.FuncAnimation(fig, draw, frames=n, blit=False)
    suffix = str(path).lower().rsplit(".", 1)[-1]
    writer = animation.PillowWriter(fps=fps) if suffix == "gif" else animation.FFMpegWriter(fps=fps)
    try:
        anim.save(str(path), writer=writer, dpi=dpi)
    except Exception as exc:
        if isinstance(exc.__context__, KeyboardInterrupt):
            raise exc.__context__ from None
        raise
    finally:
        plt.close(fig)
