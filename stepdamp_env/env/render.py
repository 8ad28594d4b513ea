"""The ``rgb_array`` picture of an episode, shared by the scalar environments."""

from __future__ import annotations

import numpy as np

from .. import kernel as K

__all__ = ["trace_rows", "render_episode"]


def trace_rows(trace: np.ndarray) -> np.ndarray:
    """t (s), velocity error (rad/s), ia, ib, injected iq (A) of every traced PWM period."""
    return np.stack([trace[:, K.TRACE.T], trace[:, K.TRACE.OMEGA_CMD] - trace[:, K.TRACE.OMEGA],
                     trace[:, K.TRACE.IA], trace[:, K.TRACE.IB], trace[:, K.TRACE.IQ_FF]])


def render_episode(rows: list[np.ndarray], title: str) -> np.ndarray:
    """RGB array (H, W, 3): velocity error and currents of the episode's ``trace_rows``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.8), dpi=80)
    canvas = FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    if rows:
        h = np.concatenate(rows, axis=1)
        t_ms = 1e3 * h[0]
        ax1.plot(t_ms, h[1], lw=0.8)
        ax2.plot(t_ms, h[2], lw=0.8, label="ia")
        ax2.plot(t_ms, h[3], lw=0.8, label="ib")
        ax2.plot(t_ms, h[4], lw=0.8, label="iq injected")
        ax2.legend(loc="upper right", fontsize=7)
    ax1.set_title(title, fontsize=9)
    ax1.set_ylabel("w_cmd - w (rad/s)")
    ax2.set_ylabel("current (A)")
    ax2.set_xlabel("t (ms)")
    fig.tight_layout()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
