"""The calibration file's format string, kind key and the writer's building blocks (SPEC section 2).

Every calibration kind builds its document from :func:`header` and :func:`channel_entry`;
:func:`model_to_dict` writes a bare sensor model in the channel form.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CHANNEL_KINDS", "FORMAT", "KIND_KEY", "TUMBLE_CHANNELS", "channel_entry", "header", "model_to_dict"]

FORMAT = "compass-calibration/1"
KIND_KEY = "model"
CHANNEL_KINDS = ("fourflip", "platform3d", "reference", "channels")
"""Kinds written in the channel form (SPEC section 2); ``channels``: a sensor model written as such
(:func:`model_to_dict`), whatever fit it came from."""
TUMBLE_CHANNELS = ("mx", "my", "mz")


def header(kind: str) -> dict:
    """The first keys of every calibration file: ``{"format": FORMAT, "model": kind}``."""
    return {"format": FORMAT, KIND_KEY: kind}


def channel_entry(direction, response: dict, *, covariance=None, response_sigma=None, joint_covariance=None,
                  angles: bool = True) -> dict:
    """One channel of the channel form (SPEC section 2).

    Parameters
    ----------
    direction : array_like, shape (3,)
        Unit sensing direction in the housing frame H.
    response : dict
        The response's JSON (:meth:`compass.response.Response.to_json`).
    covariance : array_like, shape (3, 3), optional
        Covariance of the direction (rad^2), written with ``direction_sigma_deg`` (null without it).
    response_sigma : (float, float), optional
        Standard errors of (offset, gain), output units and output units per field unit.
    joint_covariance : array_like, shape (5, 5) or (8, 8), optional
        The joint covariance of the direction (3, rad), offset and gain (the units above) whose marginals are
        ``covariance`` and ``response_sigma`` (the runtime's heading sigma then keeps their correlations:
        :class:`compass.iron_uncertainty.ChannelUncertainty`).  Finite.  8 x 8 for a cubic ``response``: its
        quadratic, cubic and quintic coefficients after the gain, in the response's units
        (1 / field unit^(k - 1)).  Written by :func:`_joint_entries`.
    angles : bool
        Add seed 000's angles ``theta_deg, gamma_deg, elevation_deg, psi_deg``.

    Returns
    -------
    dict
    """
    from ..frames import direction_sigma_deg, seed_angles

    direction = np.asarray(direction, dtype=float)
    entry: dict = {"direction": direction.tolist(), "direction_sigma_deg": None if covariance is None else
                   float(direction_sigma_deg(np.asarray(covariance, dtype=float)))}
    if angles:
        entry.update({k: float(v) for k, v in seed_angles(direction).items()})
    entry["response"] = response
    if covariance is not None:
        entry["direction_covariance"] = np.asarray(covariance, dtype=float).tolist()
    if response_sigma is not None:
        entry["response_sigma"] = {"offset": _plain(response_sigma[0]), "gain": _plain(response_sigma[1])}
    if joint_covariance is not None:
        entry.update(_joint_entries(joint_covariance))
    return entry


def _joint_entries(joint) -> dict:
    """A channel's joint covariance as its file keys: the 5 x 5 (direction 3, offset, gain) under
    ``joint_covariance``, as every reader of :data:`FORMAT` reads it, and an 8 x 8 (with a response curve's
    quadratic, cubic and quintic after the gain) whole under ``curve_joint_covariance`` too (a reader before
    that key ignores it and keeps the 5 x 5).

    Parameters
    ----------
    joint : array_like, shape (5, 5) or (8, 8)
        Units as :func:`channel_entry`'s ``joint_covariance``.

    Returns
    -------
    dict
    """
    joint = np.asarray(joint, dtype=float)
    entries = {"joint_covariance": joint[:5, :5].tolist()}
    if joint.shape == (8, 8):
        entries["curve_joint_covariance"] = joint.tolist()
    return entries


def model_to_dict(model) -> dict:
    """A sensor model's calibration document in the channel form (``"model": "channels"``), JSON-ready.

    A tumble model comes back in its equivalent channel form; :func:`compass.calibration.from_dict`
    reads it back to the same model.

    Parameters
    ----------
    model : compass.model.SensorModel

    Returns
    -------
    dict
    """
    channels = {}
    # a sigma the file left null (it took a stated prior: model.sigma_priors) is written null again
    prior_cov, prior_sigma = (None, None) if model.sigma_priors is None else model.sigma_priors[:2]
    for c, name in enumerate(model.channels):
        entry = {"direction": [float(v) for v in model.directions[c]], "response": model.responses[c].to_json()}
        if model.direction_covariance is not None:
            gone = prior_cov is not None and np.any(prior_cov[c])
            entry["direction_covariance"] = None if gone else model.direction_covariance[c].tolist()
        if model.response_sigma is not None:
            entry["response_sigma"] = {k: None if prior_sigma is not None and prior_sigma[c, i] > 0
                                       else float(model.response_sigma[c, i]) for i, k in enumerate(("offset", "gain"))}
        if model.joint_covariance is not None and model.joint_covariance[c] is not None:
            entry.update(_joint_entries(model.joint_covariance[c]))
        channels[name] = entry
    out = header("channels") | {"channels": channels, "dip_deg": model.dip_deg, "field_ut": model.field_ut}
    if model.temperature is not None and model.temperature.reference_c is not None:
        out["effects"] = [model.temperature.to_json(model.channels)]
    if model.noise is not None:
        out["noise_floor"] = [float(v) for v in model.noise]
    return out


def _plain(v):
    return None if v is None else float(v)
