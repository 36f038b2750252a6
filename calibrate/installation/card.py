"""The deviation card of a compass swing, as mariners and pilots read it.

Deviation is what a compass reads minus the magnetic heading, against heading, and the classical
five coefficients describe it (Bowditch, *The American Practical Navigator*, ch. 6):

.. math:: \\delta(\\psi) = A + B \\sin\\psi + C \\cos\\psi + D \\sin 2\\psi + E \\cos 2\\psi

``A``: constant (a yaw misalignment of the compass in the craft, or unsymmetrical soft iron);
``B``, ``C``: once a turn (hard iron, and the soft iron induced by the vertical field, fore-aft and
athwartships); ``D``, ``E``: twice a turn (symmetrical horizontal soft iron).  Fitted by linear
least squares over the rows of the swing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DeviationCard", "deviation_card"]

COEFFICIENTS = ("A", "B", "C", "D", "E")


@dataclass(frozen=True)
class DeviationCard:
    """Deviation against heading and its classical coefficients.

    Attributes
    ----------
    heading_deg : ndarray, shape (n,)
        The magnetic heading of each row (the reference), degrees.
    deviation_deg : ndarray, shape (n,)
        Compass minus magnetic heading, degrees in (-180, 180].
    coefficients_deg : dict
        ``A`` to ``E``, degrees.
    residual_rms_deg : float
        What the five terms leave.
    """

    heading_deg: np.ndarray
    deviation_deg: np.ndarray
    coefficients_deg: dict
    residual_rms_deg: float

    def curve(self, heading_deg) -> np.ndarray:
        """The five-term deviation at ``heading_deg``."""
        return _design(np.asarray(heading_deg, dtype=float)) @ np.array([self.coefficients_deg[k] for k in COEFFICIENTS])

    def line(self) -> str:
        c = self.coefficients_deg
        return " ".join(f"{k} {c[k]:+.2f}" for k in COEFFICIENTS) + f" deg (residual {self.residual_rms_deg:.2f} deg)"

    def to_json(self) -> dict:
        return {"coefficients_deg": {k: float(v) for k, v in self.coefficients_deg.items()},
                "residual_rms_deg": float(self.residual_rms_deg),
                "max_deviation_deg": float(np.max(np.abs(self.deviation_deg)))}


def _design(heading_deg: np.ndarray) -> np.ndarray:
    psi = np.radians(heading_deg)
    return np.column_stack([np.ones_like(psi), np.sin(psi), np.cos(psi), np.sin(2 * psi), np.cos(2 * psi)])


def deviation_card(compass_deg, magnetic_deg) -> DeviationCard:
    """The card of a compass reading ``compass_deg`` where the magnetic heading was ``magnetic_deg``."""
    magnetic = np.mod(np.asarray(magnetic_deg, dtype=float), 360.0)
    deviation = np.mod(np.asarray(compass_deg, dtype=float) - magnetic + 180.0, 360.0) - 180.0
    design = _design(magnetic)
    coef, *_ = np.linalg.lstsq(design, deviation, rcond=None)
    residual = deviation - design @ coef
    return DeviationCard(magnetic, deviation, dict(zip(COEFFICIENTS, map(float, coef))),
                         float(np.sqrt(np.mean(residual**2))))


def plot_cards(before: DeviationCard, after: DeviationCard | None, path, title: str = "") -> None:
    """Deviation against heading, before and after the installation calibration (points and five-term curves)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = np.linspace(0.0, 360.0, 361)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for card, name, colour in ((before, "before (bench model only)", "tab:red"),
                               (after, "after (installed)", "tab:blue")):
        if card is None:
            continue
        ax.plot(card.heading_deg, card.deviation_deg, ".", ms=2, alpha=0.3, color=colour)
        ax.plot(grid, card.curve(grid), "-", color=colour, label=f"{name}: {card.line()}")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlim(0, 360)
    ax.set_xticks(range(0, 361, 45))
    ax.set_xlabel("magnetic heading, deg")
    ax.set_ylabel("deviation (compass - magnetic), deg")
    ax.set_title(title or "Deviation card")
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
