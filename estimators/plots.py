"""Figures of a normal-force evaluation, like the paper's Figs. 5-10 (matplotlib, Agg).

`make_figures` writes PNGs next to ``estimation.json`` (`estimators.evaluate`):

* ``forces.png`` (Figs. 5, 7): f_z of each wheel over time: ground truth (blue), the
  quasi-static method of ref. [13] (red) and the full dynamics (green), plus the
  cylinder-force closure (purple) when logged. Panels laid out as the wheels sit on the
  machine: front row FL, FR; rear row RL, RR.
* ``errors.png`` (Figs. 6, 8): absolute errors of the same methods in percent of the static
  wheel load, as 0.25 s moving averages (the raw samples carry vibration that would hide
  the trend), with each method's mean error in the legend.
* ``d_beta.png`` (Fig. 9): optimal D and beta of eq. (30) on sliding windows, with the global
  optimum dashed.
* ``contact_loss.png`` (Fig. 10): the rear wheels' f_z with the contact-loss variant
  (Sec. III-B) and the logged contact flags shaded, whole run and a zoom on the busiest
  stretch; only when a wheel loses contact.
* ``equilibrium_rows.png``: ``A f_gt - b`` of the three equilibrium rows (eqs. 25-28): zero
  in a consistent log; what is left is a dynamics error, not a fourth-row one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["make_figures"]

COLORS = {"ground truth": "tab:blue", "quasi-static/d-beta": "tab:red",
          "full/d-beta": "tab:green", "full/cylinder-force": "tab:purple",
          "full/calibrated": "tab:orange"}
LABELS = {"quasi-static/d-beta": "quasi-static [13] (d-beta)",
          "full/d-beta": "full dynamics (d-beta, default D)",
          "full/cylinder-force": "full dynamics (cylinder-force)",
          "full/calibrated": "full dynamics (calibrated D, beta)"}
LAYOUT = {"FL": (0, 0), "FR": (0, 1), "RL": (1, 0), "RR": (1, 1)}
WHEELS = ("FL", "RL", "FR", "RR")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1 or len(x) < n:
        return x
    k = np.ones(n) / n
    return np.convolve(np.pad(x, (n // 2, n - 1 - n // 2), mode="edge"), k, mode="valid")


def _wheel_axes(plt, title: str):
    fig, axes = plt.subplots(2, 2, figsize=(13, 7.5), sharex=True, sharey=True,
                             constrained_layout=True)
    fig.suptitle(title, fontsize=12)
    return fig, {w: axes[r][c] for w, (r, c) in LAYOUT.items()}


def _methods(results: dict) -> list[str]:
    return [m for m in ("quasi-static/d-beta", "full/d-beta", "full/cylinder-force")
            if m in results]


def make_figures(out_dir, *, time, rows, gt, results, static_load, sliding=None,
                 calibration=None, equilibrium=None, scenario: str = "") -> list[Path]:
    """Write the evaluation figures; returns their paths.

    Args:
        out_dir: Folder for the PNGs.
        time: Log time [s], shape (N,).
        rows: Indices of the scored samples (after settling), shape (M,).
        gt: Ground-truth f_z [N], shape (N, 4), order FL, RL, FR, RR.
        results: Method name -> `estimators.estimator.BatchEstimate` over the whole log.
        static_load: Static wheel load m g / 4 [N].
        sliding: The sliding-window calibration of the report (``time``, ``D``, ``beta``),
            or None.
        calibration: The report's ``calibration`` (for the global optimum), or None.
        equilibrium: ``A f_gt - b`` over ``rows``, shape (M, 3), or None.
        scenario: Scenario name for the titles.
    """
    plt = _pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    t = np.asarray(time)[rows]
    g = np.asarray(gt)[rows]
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.01
    smooth = max(1, int(round(0.25 / dt)))
    methods = _methods(results)

    # Figs. 5 / 7: forces.
    fig, ax = _wheel_axes(plt, f"Normal forces f_z ({scenario}): ground truth vs estimates")
    for k, w in enumerate(WHEELS):
        a = ax[w]
        a.plot(t, g[:, k] / 1e3, color=COLORS["ground truth"], lw=2.5, alpha=0.6,
               label="ground truth (MuJoCo)")
        for m in methods:
            a.plot(t, results[m].normal_forces[rows, k] / 1e3, color=COLORS[m], lw=0.8,
                   alpha=0.8, label=LABELS[m])
        a.set_title(w)
        a.grid(alpha=0.3)
    for w in ("FL", "RL"):
        ax[w].set_ylabel("f_z [kN]")
    for w in ("RL", "RR"):
        ax[w].set_xlabel("time [s]")
    handles, labels = ax["FL"].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=9)
    paths.append(_save(fig, out / "forces.png", plt))

    # Figs. 6 / 8: absolute errors.
    fig, ax = _wheel_axes(plt, f"Absolute f_z error ({scenario}), % of the static wheel load "
                               f"{static_load / 1e3:.2f} kN (0.25 s moving mean)")
    for k, w in enumerate(WHEELS):
        a = ax[w]
        for m in methods:
            e = 100 * np.abs(results[m].normal_forces[rows, k] - g[:, k]) / static_load
            # Floor at 1e-3 %: exact samples (a wheel off the ground) would plunge the log axis.
            a.plot(t, np.maximum(_moving_mean(e, smooth), 1e-3), color=COLORS[m], lw=1.0,
                   label=f"{LABELS[m]}: mean {e.mean():.2f} %")
        a.set_title(w)
        a.grid(alpha=0.3)
        a.legend(loc="upper right", fontsize=8)
        a.set_yscale("log")
        a.set_ylim(bottom=1e-3)
    for w in ("FL", "RL"):
        ax[w].set_ylabel("|error| [%]")
    for w in ("RL", "RR"):
        ax[w].set_xlabel("time [s]")
    paths.append(_save(fig, out / "errors.png", plt))

    # Fig. 9: optimal D and beta over time.
    if sliding is not None and len(sliding.get("time", [])) and np.isfinite(
            np.asarray(sliding["D"], float)).any():
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 6), sharex=True,
                                     constrained_layout=True)
        ts = np.asarray(sliding["time"])
        a1.plot(ts, sliding["D"], "o-", ms=3, color="tab:blue", label="D* (window)")
        a2.plot(ts, np.asarray(sliding["beta"]) / 1e3, "o-", ms=3, color="tab:red",
                label="beta* (window)")
        glob = (calibration or {}).get("global")
        if glob:
            a1.axhline(glob["D"], ls="--", color="k", lw=1, label=f"global D* {glob['D']:.3f}")
            a2.axhline(glob["beta"] / 1e3, ls="--", color="k", lw=1,
                       label=f"global beta* {glob['beta'] / 1e3:.2f} kN")
        a1.set_ylabel("D* [-]")
        a2.set_ylabel("beta* [kN]")
        a2.set_xlabel("time [s] (window centre)")
        for a in (a1, a2):
            a.grid(alpha=0.3)
            a.legend(loc="upper right", fontsize=8)
        fig.suptitle(f"Optimal D and beta of eq. (30) on {sliding['window_s']:.2g} s windows "
                     f"({scenario})")
        paths.append(_save(fig, out / "d_beta.png", plt))
    else:
        _remove_stale(out / "d_beta.png")

    # Fig. 10: contact loss, rear wheels.
    flags = results["full/d-beta"].in_contact[rows]
    if (~flags).any():
        paths.append(_contact_loss(plt, out, t, g, results, rows, flags, scenario))
    else:
        _remove_stale(out / "contact_loss.png")

    if equilibrium is not None and len(equilibrium):
        fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True, constrained_layout=True)
        names = ("force z [kN]", "roll moment [kN m]", "pitch moment [kN m]")
        for i, a in enumerate(axes):
            a.plot(t, np.asarray(equilibrium)[:, i] / 1e3, lw=0.6, color="tab:gray")
            a.set_ylabel(names[i])
            a.grid(alpha=0.3)
        axes[-1].set_xlabel("time [s]")
        fig.suptitle(f"Equilibrium rows with the ground truth, A f_gt - b ({scenario}): "
                     "zero in a consistent log")
        paths.append(_save(fig, out / "equilibrium_rows.png", plt))
    return paths


def _contact_loss(plt, out, t, g, results, rows, flags, scenario):
    fig, axes = plt.subplots(2, 2, figsize=(13, 7), constrained_layout=True,
                             gridspec_kw={"width_ratios": [2, 1]})
    # Zoom +-1.5 s around the contact-flag change with the most other changes near it (a
    # hand-over from one rear wheel to the other).
    changes = np.flatnonzero(np.r_[False, (np.diff(flags.astype(int), axis=0) != 0).any(1)])
    if changes.size:
        near = [(np.abs(t[changes] - t[i]) <= 1.5).sum() for i in changes]
        tc = t[changes[int(np.argmax(near))]]
    else:
        tc = t[len(t) // 2]
    zoom = (tc - 1.5, tc + 1.5)
    est = results["full/d-beta"].normal_forces[rows]
    for r, (k, w) in enumerate(((1, "RL"), (3, "RR"))):
        for c, lim in enumerate((None, zoom)):
            a = axes[r][c]
            a.plot(t, g[:, k] / 1e3, color=COLORS["ground truth"], lw=2.5, alpha=0.6,
                   label="ground truth (MuJoCo)")
            a.plot(t, est[:, k] / 1e3, color=COLORS["full/d-beta"], lw=0.8,
                   label="full dynamics, contact-loss variant (III-B)")
            off = ~flags[:, k]
            a.fill_between(t, 0, 1, where=off, transform=a.get_xaxis_transform(),
                           color="tab:red", alpha=0.15, lw=0, label="contact flag off")
            if lim is not None:
                a.set_xlim(*lim)
            a.set_title(f"{w}" + (" (zoom)" if lim is not None else ""))
            a.grid(alpha=0.3)
            a.set_ylabel("f_z [kN]")
    axes[1][0].set_xlabel("time [s]")
    axes[1][1].set_xlabel("time [s]")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=3, fontsize=9)
    fig.suptitle(f"Rear wheels with contact loss ({scenario}): logged contact flags shaded")
    return _save(fig, out / "contact_loss.png", plt)


def _remove_stale(path: Path) -> None:
    """Drop a figure an earlier evaluation left that this one does not make."""
    if path.is_file():
        path.unlink()


def _save(fig, path: Path, plt) -> Path:
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
