"""Plots of a climb (matplotlib, Agg backend): CoM path, contact forces against their cones, the
most loaded joints' torques against their limits, controller tick times; and a film strip."""
from __future__ import annotations

import pathlib

import numpy as np

from climb_core.contact import LIMBS


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_climb(result, path: str | pathlib.Path, n_joints: int = 4) -> pathlib.Path:
    """One PNG with four panels; returns its path."""
    plt = _pyplot()
    log = result.log
    t = np.asarray(log.times)
    com = np.asarray(log.com)
    base = np.asarray(log.base)
    tau = np.asarray(log.tau)
    fig, axes = plt.subplots(2, 2, figsize=(13, 9))
    # CoM path (side view, x forward to the ladder, z up) coloured by time
    ax = axes[0, 0]
    if len(com):
        sc = ax.scatter(com[:, 0], com[:, 2], c=t, s=3, cmap="viridis")
        ax.plot(base[:, 0], base[:, 2], color="0.6", lw=0.8, label="base (sim)")
        fig.colorbar(sc, ax=ax, label="t [s]")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_title("CoM path (side view)")
    ax.axis("equal")
    ax.legend(loc="best", fontsize=8)
    # contact forces: tangential / (mu * normal) per unilateral contact (the cone is <= 1)
    ax = axes[0, 1]
    mu_of = {}
    if result.backend is not None:
        mu_of = {name: float(s.friction) for name, s in result.backend.env.surfaces.items()}
    for limb in LIMBS:
        samples = log.loads[limb]
        use, tt, normal = [], [], []
        for ti, s in zip(t, samples):
            if s is None or s[0] < 1.0:
                continue
            mu = mu_of.get(s[2], np.nan)
            tt.append(ti)
            use.append(s[1] / (mu * s[0]))
            normal.append(s[0])
        if tt:
            ax.plot(tt, use, ".", ms=2, label=f"{limb}")
    ax.axhline(1.0, color="r", lw=1.0, ls="--", label="friction cone")
    ax.set_ylim(0.0, 1.5)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("|f_t| / (mu f_n) [-]")
    ax.set_title("contact forces against their friction cones (sim truth)")
    ax.legend(loc="upper right", fontsize=8, markerscale=4)
    # the most loaded joints against their limits
    ax = axes[1, 0]
    if len(tau) and len(log.effort_limits):
        ratio = np.max(np.abs(tau), axis=0) / log.effort_limits
        top = np.argsort(ratio)[::-1][:n_joints]
        for j in top:
            line, = ax.plot(t, tau[:, j] / log.effort_limits[j], lw=0.8,
                            label=f"{log.joint_names[j]} (limit {log.effort_limits[j]:.0f} N m)")
        ax.axhline(1.0, color="r", lw=1.0, ls="--")
        ax.axhline(-1.0, color="r", lw=1.0, ls="--")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tau / effort limit [-]")
    ax.set_title(f"the {n_joints} most loaded joints")
    ax.legend(loc="lower left", fontsize=8)
    # tick times
    ax = axes[1, 1]
    ticks = np.asarray(log.tick_ms)
    if len(ticks):
        tt = np.arange(len(ticks)) * (t[-1] / max(len(ticks) - 1, 1) if len(t) else 1.0)
        ax.plot(tt, ticks, ",", color="C0", alpha=0.5)
        for q, ls in ((50, "-"), (99, "--")):
            ax.axhline(np.percentile(ticks, q), color="k", ls=ls, lw=0.8, label=f"p{q} {np.percentile(ticks, q):.2f} ms")
        ax.axhline(5.0, color="r", lw=1.0, label="control period 5 ms")
        ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tick [ms]")
    ax.set_title("controller tick time (state in -> command out)")
    ax.legend(loc="upper right", fontsize=8)
    s = result.summary
    fig.suptitle(f"{s['robot']} on {s['ladder']}: {s['rungs_requested']}-step climb, {s.get('mode', '')} mode, "
                 f"rungs reached {s['rungs_reached']}, {'success' if s['success'] else 'FAILED'}")
    return _save(plt, fig, path)


def film_strip(frames: list, path: str | pathlib.Path) -> pathlib.Path:
    """The (time, RGB) frames side by side with their sim times."""
    plt = _pyplot()
    n = max(len(frames), 1)
    fig, axes = plt.subplots(1, n, figsize=(2.4 * n, 3.4))
    axes = np.atleast_1d(axes)
    for ax, (time_s, image) in zip(axes, frames):
        ax.imshow(image)
        ax.set_title(f"t = {time_s:.1f} s", fontsize=9)
        ax.axis("off")
    return _save(plt, fig, path)


def _save(plt, fig, path: str | pathlib.Path) -> pathlib.Path:
    """Lay out, write (PNG, 90 dpi, parent folders created) and close the figure."""
    fig.tight_layout()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
