"""Report plots for a person: fitted curves and residuals (matplotlib, Agg backend, no display)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from compass.io.atomic import save_figure  # noqa: E402

__all__ = ["plot_fit", "plot_residuals", "plot_tumble", "plot_platform3d"]

_FLIPS = ("flip 0", "flip 90", "flip 180", "flip 270")


def plot_fit(rec, result, path) -> Path:
    """Measured and fitted output against turntable angle, one panel per channel and flip."""
    c = len(rec.channels)
    fig, axes = plt.subplots(c, 4, figsize=(14, 2.6 * c), sharex=True, squeeze=False)
    fitted = rec.outputs - result.residuals
    for j, name in enumerate(rec.channels):
        for k in range(4):
            ax = axes[j, k]
            m = rec.flip_index == k
            order = np.argsort(np.mod(rec.platform_deg[m], 360.0))
            phi = np.mod(rec.platform_deg[m], 360.0)[order]
            ax.plot(phi, rec.outputs[m, j][order], ".", ms=2, color="0.5", label="measured")
            ax.plot(phi, fitted[m, j][order], "-", lw=1.2, color="C0", label=f"fit ({result.method})")
            if j == 0:
                ax.set_title(_FLIPS[k])
            if k == 0:
                ax.set_ylabel(f"{name} output")
            if j == c - 1:
                ax.set_xlabel("turntable angle (deg)")
    axes[0, 0].legend(loc="best", fontsize=7)
    fig.suptitle(f"Four-flip calibration: measured and fitted output ({rec.path})", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def plot_residuals(rec, residual_sets: dict, path, noise=None, unit: str = "output units") -> Path:
    """Residuals against turntable angle (per flip, per channel) and against time.

    Parameters
    ----------
    residual_sets : dict of str to ndarray (n, c)
        Label -> residuals, e.g. {"before": r0, "after": r1}.
    noise : ndarray (c,), optional
        Noise floor, drawn as +-1 sigma bands.
    unit : str
        The channels' output unit (the recording's), for the axis labels.
    """
    c = len(rec.channels)
    has_time = rec.t_s is not None
    cols = 5 if has_time else 4
    fig, axes = plt.subplots(c, cols, figsize=(3.2 * cols, 2.4 * c), squeeze=False)
    for j, name in enumerate(rec.channels):
        for k in range(4):
            ax = axes[j, k]
            m = rec.flip_index == k
            order = np.argsort(np.mod(rec.platform_deg[m], 360.0))
            for i, (label, r) in enumerate(residual_sets.items()):
                ax.plot(np.mod(rec.platform_deg[m], 360.0)[order], r[m, j][order], ".", ms=1.5,
                        color=f"C{i}", label=label, alpha=0.7)
            if noise is not None:
                ax.axhspan(-noise[j], noise[j], color="0.85", zorder=0)
            if j == 0:
                ax.set_title(_FLIPS[k])
            if k == 0:
                ax.set_ylabel(f"{name} residual ({unit})")
            if j == c - 1:
                ax.set_xlabel("platform_deg (turntable angle, deg)")
        if has_time:
            ax = axes[j, 4]
            for i, (label, r) in enumerate(residual_sets.items()):
                ax.plot(rec.t_s, r[:, j], ".", ms=1.5, color=f"C{i}", alpha=0.7)
            if j == 0:
                ax.set_title("against time")
            if j == c - 1:
                ax.set_xlabel("t_s (s)")
    axes[0, 0].legend(loc="best", fontsize=7, markerscale=4)
    fig.suptitle("Residuals (grey band: noise floor +-1 sigma)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def plot_tumble(mag: np.ndarray, result, path) -> Path:
    """A tumble calibration for a person: where the field pointed, and |B| before and after.

    Parameters
    ----------
    mag : ndarray, shape (n, 3)
        Raw magnetometer samples the fit used (recording units).
    result : calibrate.tumble.TumbleResult
    """
    calibrated = result.calibrated(mag)
    norm = np.linalg.norm(calibrated, axis=1)
    unit = calibrated / norm[:, None]
    raw_norm = np.linalg.norm(mag, axis=1)  # as recorded: no centring (a hard iron shows as a wide spread)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax = axes[0]
    ax.scatter(np.degrees(np.arctan2(unit[:, 1], unit[:, 0])), np.degrees(np.arcsin(np.clip(unit[:, 2], -1, 1))),
               s=2, alpha=0.5)
    ax.set_xlim(-180, 180)
    ax.set_ylim(-90, 90)
    ax.set_xlabel("azimuth of the field in the sensor frame (deg)")
    ax.set_ylabel("elevation (deg)")
    missing = result.coverage.missing
    ax.set_title(f"coverage: {result.coverage.fraction:.0%} of the sphere"
                 + (f"; never along {', '.join(missing)}" if missing else ""))
    ax = axes[1]
    ax.plot(raw_norm / np.median(raw_norm), ".", ms=1.5, color="0.6", label="raw |m|, as recorded")
    ax.plot(norm / np.median(norm), ".", ms=1.5, color="C0", label=f"calibrated ({result.ellipsoid})")
    ax.set_xlabel("sample")
    ax.set_ylabel("|m| / its median")
    ax.legend(loc="best", fontsize=7, markerscale=5)
    ax.set_title("field magnitude, before and after")
    ax = axes[2]
    for j, name in enumerate("xyz"):
        ax.plot(mag[:, j], calibrated[:, j], ".", ms=1, label=name)
    ax.set_xlabel("raw (recording units)")
    ax.set_ylabel("calibrated")
    ax.legend(loc="best", fontsize=7, markerscale=5)
    ax.set_title("per axis: raw against calibrated")
    fig.tight_layout()
    return _save(fig, path)


def plot_platform3d(rec, result, path) -> Path:
    """3-D platform residuals: every magnetometer and tilt-sensor channel against the outer gimbal angle
    and, when the recording has ``t_s``, against time, with the noise floor (repeated poses) as a band.

    Parameters
    ----------
    rec : compass.io.platform3d.Platform3DRecording
    result : calibrate.platform3d.Platform3DResult
        Fitted to ``rec``; its residuals are those of the final model (after the diagnosis).
    """
    channels = [("mx", "my", "mz")[i] for i in range(3)] + list(rec.tilt_columns)
    residuals = np.column_stack([result.residuals_mag, result.residuals_tilt])
    noise = [result.noise_mag, result.noise_tilt]
    noise = None if any(n is None for n in noise) else np.concatenate(noise)
    units = ["magnetometer output"] * 3 + ["tilt-sensor output"] * len(rec.tilt_columns)
    has_time = rec.t_s is not None
    cols = 2 if has_time else 1
    fig, axes = plt.subplots(len(channels), cols, figsize=(5.5 * cols, 1.9 * len(channels)), squeeze=False,
                             sharex="col")
    outer = np.mod(rec.angles_deg[:, 0], 360.0)
    for j, name in enumerate(channels):
        for k, (x, label) in enumerate([(outer, "platform_z_deg (outer gimbal, deg)")]
                                       + ([(rec.t_s, "t_s (s)")] if has_time else [])):
            ax = axes[j, k]
            if noise is not None:
                ax.axhspan(-noise[j], noise[j], color="0.85", zorder=0, label="noise floor (+-1 sigma)")
            ax.plot(x, residuals[:, j], ".", ms=2, color="C0", label="residual")
            ax.axhline(0.0, color="0.4", lw=0.6)
            if k == 0:
                ax.set_ylabel(f"{name} residual\n({units[j]})", fontsize=8)
            if j == len(channels) - 1:
                ax.set_xlabel(label)
    axes[0, 0].legend(loc="best", fontsize=7)
    claimed = [] if result.diagnosis is None else [e["name"] for e in result.diagnosis.effects]
    effects = ", ".join(claimed) or "none"
    fig.suptitle(f"3-D platform calibration: residuals of the final model (effects added: {effects}; {rec.path})",
                 fontsize=9)
    fig.tight_layout()
    return _save(fig, path)


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=110)  # atomic, the user's umask; --force is checked by the command
    plt.close(fig)
    return path
