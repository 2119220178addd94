"""Rendering of :class:`~netsense.env.NetSenseEnv`: an ``ansi`` table and matplotlib figures.

``ansi``: one line per agent (up to 12, then a summary) with its normalised error, how
many freshness indices are finite, the largest finite age, its in-neighbours and whether it
transmits; faulty agents (crashed, liars) are starred and left out of the mean error.
``rgb_array``/``human``: the current graph ``G[k]`` with agents coloured by ``log10`` of
their error, next to the error curves so far (every agent for ``N <= 10``,
otherwise mean and max). Matplotlib is imported lazily and drawn with the Agg canvas.
"""

from __future__ import annotations

import numpy as np

from netsense.kernels import update as kernels

_MAX_ROWS = 12


def ansi_table(env) -> str:
    """The compact text table of the current step."""
    c = env.core
    if not c._seeded:
        return "(not reset)"
    k = int(c.k[0])
    err = c.errors[0]
    tau = c.tau[0]
    finite = (tau != kernels.OMEGA).sum(1)
    age = np.where(tau == kernels.OMEGA, -1, tau).max(1)
    alive = c.alive
    lines = [f"{env.scenario_id}  k = {k}/{c.horizon}  mean error = {err[alive].mean():.3g}  "
             f"max error = {err[alive].max():.3g}  messages = {int(c.messages_sent[0])}"
             + ("" if alive.all() else "  (* faulty, not in the mean)"),
             f"{'agent':>9} {'error':>10} {'finite tau':>10} {'max age':>7} {'tx':>3}  "
             "in-neighbours"]
    N = c.N
    rows = range(N) if N <= _MAX_ROWS else range(_MAX_ROWS - 2)
    for i in rows:
        nb = [int(v) for v, ok in zip(c.nbr[0, i], c.msg[0, i], strict=True) if ok]
        name = f"sensor_{i}" + ("" if alive[i] else "*")
        lines.append(f"{name:>9} {err[i]:10.3g} {int(finite[i]):>6}/{c.M:<3} "
                     f"{int(age[i]):>7} {'y' if c.transmit[0, i] else 'n':>3}  {nb}")
    if N > _MAX_ROWS:
        lines.append(f"{'...':>9} ({N - len(rows)} more agents; median error "
                     f"{np.median(err):.3g}, all-finite agents {(finite == c.M).sum()})")
    return "\n".join(lines)


class FigureRenderer:
    """Draws the graph + error-curve figure; reuses one Agg figure."""

    def __init__(self) -> None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.fig = Figure(figsize=(8, 3.6), dpi=80)
        self.canvas = FigureCanvasAgg(self.fig)
        self._window = None
        self._pos = None

    def _layout(self, N: int) -> np.ndarray:
        if self._pos is None or self._pos.shape[0] != N:
            ang = 2 * np.pi * np.arange(N) / N
            self._pos = np.stack([np.cos(ang), np.sin(ang)], 1)
        return self._pos

    def draw(self, env) -> np.ndarray:
        """The figure of the current step as an ``(H, W, 3)`` uint8 image."""
        c = env.core
        self.fig.clear()
        ax_g = self.fig.add_axes((0.01, 0.06, 0.36, 0.84))
        ax_c = self.fig.add_axes((0.39, 0.15, 0.015, 0.7))
        ax_e = self.fig.add_axes((0.53, 0.14, 0.44, 0.76))
        N = c.N
        pos = self._layout(N)
        if c._seeded:
            adj = c.adjacency[0]
            msg_from = np.zeros((N, N), bool)
            rows, slots = np.nonzero(c.msg[0])
            msg_from[rows, c.nbr[0][rows, slots]] = True
            i, l = np.nonzero(adj)
            if i.size:  # one quiver artist for all edges l -> i (fast for N = 100)
                start, delta = pos[l], 0.9 * (pos[i] - pos[l])
                ax_g.quiver(start[:, 0], start[:, 1], delta[:, 0], delta[:, 1],
                            color=np.where(msg_from[i, l], "k", "0.75"), angles="xy",
                            scale_units="xy", scale=1, width=0.004, headwidth=4)
            err = np.log10(np.maximum(c.errors[0], 1e-12))
        else:
            err = np.zeros(N)
        sc = ax_g.scatter(pos[:, 0], pos[:, 1], c=err, cmap="viridis", vmin=-6, vmax=1,
                          s=max(12, 300 // max(N, 1) * 3), zorder=3)
        if N <= 20:
            for i in range(N):
                ax_g.text(*(pos[i] * 1.2), str(i), ha="center", va="center", fontsize=7)
        cb = self.fig.colorbar(sc, cax=ax_c)
        cb.set_label("log10 error", fontsize=7)
        ax_c.tick_params(labelsize=6)
        ax_g.set_title(f"G[{int(c.k[0]) if c._seeded else 0}]", fontsize=9)
        ax_g.set_xlim(-1.35, 1.35)
        ax_g.set_ylim(-1.35, 1.35)
        ax_g.set_aspect("equal")
        ax_g.axis("off")
        hist = np.array(env.history) if env.history else np.zeros((0, N))
        steps = np.arange(1, hist.shape[0] + 1)
        if hist.shape[0]:
            h = np.maximum(hist, 1e-12)
            if N <= 10:
                for i in range(N):
                    ax_e.semilogy(steps, h[:, i], lw=1, label=f"sensor_{i}")
                ax_e.legend(fontsize=6, ncol=2)
            else:
                ax_e.semilogy(steps, h.mean(1), label="mean")
                ax_e.semilogy(steps, h.max(1), label="max")
                ax_e.legend(fontsize=7)
        ax_e.set_xlim(0, c.horizon)
        ax_e.set_xlabel("k", fontsize=8)
        ax_e.set_ylabel("normalised error", fontsize=8)
        ax_e.tick_params(labelsize=7)
        ax_e.set_title(env.scenario_id, fontsize=9)
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()

    def show(self) -> None:
        """Show the last drawn figure in a window when an interactive backend exists."""
        import matplotlib

        if matplotlib.get_backend().lower() in ("agg", "pdf", "svg", "ps", "cairo",
                                                "template") or \
                "inline" in matplotlib.get_backend().lower():
            return
        import matplotlib.pyplot as plt  # pragma: no cover - needs a display

        img = np.asarray(self.canvas.buffer_rgba())  # pragma: no cover
        if self._window is None:  # pragma: no cover
            fig = plt.figure()
            self._window = (fig, fig.add_subplot(111).imshow(img))
            fig.axes[0].axis("off")
        else:  # pragma: no cover
            self._window[1].set_data(img)
        plt.pause(0.001)  # pragma: no cover

    def close(self) -> None:
        if self._window is not None:  # pragma: no cover
            import matplotlib.pyplot as plt

            plt.close(self._window[0])
            self._window = None
