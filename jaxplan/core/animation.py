"""Writing matplotlib animations to files, for every system's viewer."""
from __future__ import annotations


def save_animation(fig, draw, n: int, path, *, fps: int, dpi: int) -> None:
    """Render ``draw(i)`` for ``i < n`` into ``path`` (.gif with Pillow, else ffmpeg) and close ``fig``."""
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib import animation  # noqa: PLC0415

    anim = animation.FuncAnimation(fig, draw, frames=n, blit=False)
    suffix = str(path).lower().rsplit(".", 1)[-1]
    writer = animation.PillowWriter(fps=fps) if suffix == "gif" else animation.FFMpegWriter(fps=fps)
    try:
        anim.save(str(path), writer=writer, dpi=dpi)
    finally:
        plt.close(fig)
