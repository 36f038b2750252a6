"""One diagnosis record and one formatter for every kind's residual diagnosis (SPEC section 4)."""

from __future__ import annotations

from .evidence import STRUCTURE_P, VERDICTS, added_step_lines, remark_lines, residual_line

__all__ = ["Diagnosis", "cost_lines", "format_diagnosis"]

_NOT_JUDGED = "not judged: no repeated samples to measure the noise floor independently"


class Diagnosis:
    """Base of every kind's diagnosis record.

    A record has ``block`` (the calibration file's ``diagnosis``, SPEC section 4: ``noise_floor``,
    ``steps``, ``effects``, ``residual_rms_before``, ``residual_rms_after``, ``unexplained``) and
    ``effects`` (the file's ``effects`` entries: ``{"name", "form", "reference", "parameters"}``),
    besides what its kind's model needs (the fit with the effects).
    """

    block: dict
    effects: tuple

    @property
    def unexplained(self) -> bool | None:
        """Structure above the noise floor that no modelled effect explains; None: not judged."""
        return self.block["unexplained"]

    def format(self, unit: str = "output units") -> str:
        """The block in words (:func:`format_diagnosis`)."""
        return format_diagnosis(self.block, unit)


def format_diagnosis(block: dict, unit: str = "output units") -> str:
    """Any kind's diagnosis block as lines for a person: each step with its evidence, before and after.

    Parameters
    ----------
    block : dict
        The diagnosis block (SPEC section 4).  Kind-specific keys it reads when present:
        ``subject`` (what the residual is), ``noise_floor_source``, ``structure_test.name``, a base
        step's ``kind`` (the tumble's ellipsoid), ``alignment`` (the tumble's mag-to-accel rotation, not
        an effect, so not a step), and what moved:
        ``calibration_change`` (four-flip), ``offset_change`` (fits against known inputs),
        ``hard_iron_change`` (tumble).
    unit : str
        The unit of the residual.
    """
    subject = f" of {block['subject']}" if block.get("subject") else ""
    source = block.get("noise_floor_source", "estimated from the data")
    lines = [f"Residual diagnosis{subject} (noise floor {block['noise_floor']:.4g} {unit}, {source})"]
    for step in block["steps"]:
        if step.get("model") == "base":
            kind = f" ({step['kind']} ellipsoid)" if "kind" in step else ""
            if step.get("refitted") is False:  # made from more than the residual (the tumble's gyro-aided fit)
                kind = kind[:-1] + ", as fitted with the gyro, not refitted to |m|)" if kind else " (as fitted)"
            lines.append(f"  base model{kind}: residual rms {step['residual_rms']:.4g}")
        else:
            lines += added_step_lines(step)
    alignment = block.get("alignment")
    if alignment:
        # the evidence says whether it was applied and why, with its delta-BIC (printed here too it
        # stood as if for the rotation beside a summary giving the other sign)
        lines.append(f"  mag-to-accel rotation: residual rms {alignment['residual_rms']:.4g}; {alignment['evidence']}")
    lines += remark_lines(block)
    added = len(block["steps"]) > 1 and block["effects"]
    change = block.get("calibration_change")
    if change and len(block["steps"]) > 1:
        moved = ", ".join(f"{name} {c['direction_change_deg']:.3f} deg (sigma {c['sigma_deg']:.3f})"
                          for name, c in change["channels"].items())
        lines.append(f"  the calibration moved: directions {moved}; dip {change['dip_change_deg']:+.3f} deg")
    if added and "offset_change" in block:
        ch = block["offset_change"]
        moved = ", ".join(f"{n} {v:+.4g}" for n, v in zip(ch["channels"], ch["value"]))
        lines.append(f"  the offsets (now at the effects' reference) moved by {moved} {unit}")
    if added and "hard_iron_change" in block:
        ch = block["hard_iron_change"]
        moved = ", ".join(f"{v:+.4g} (sigma {s:.2g})" for v, s in zip(ch["value"], ch["sigma"]))
        lines.append(f"  the hard iron moved by {moved} {unit}")
    verdict = (block.get("not_judged", _NOT_JUDGED) if block["unexplained"] is None
               else VERDICTS[bool(block["unexplained"])])
    if block.get("not_judged") and block["unexplained"] is not None:
        lines.append(f"  left out of the verdict: {block['not_judged']}")
    test = (block.get("structure_test") or {}).get("name", "structure test")
    form = block.get("response_form_test")  # the four-flip's: the fitted response against a general curve
    if form and form["p_value"] < STRUCTURE_P:
        drops = ", ".join(f"{name} {v:.0f}" for name, v in form["delta_chi2"].items())
        kept = ("the nearest curve the vocabulary has" if "nonlinear_response" in block["effects"]
                else "the linear response (the loop named no curve)")
        cubic = form.get("cubic_delta_chi2")  # a linear response's: the vocabulary's cubic alone, the judged channels
        cubic = "" if cubic is None else f"; the odd cubic alone: chi2 {cubic:.0f} on {form['cubic_dof']} dof"
        lines.append(f"  the fitted response's curve is not the vocabulary's form: a general curve of each channel's "
                     f"field ({form['curve']}) would take chi2 {drops} ({form['dof']} dof each{cubic}, p = "
                     f"{form['p_value']:.2g}); the file keeps {kept}")
        if block["unexplained"] is True and block.get("unexplained_by") == "response_form_test":
            verdict = "UNEXPLAINED: the fitted response's curve is not a form the model has; the rest is white"
    lines.append(residual_line(block, verdict, test))
    lines += cost_lines(block.get("unexplained_cost"))
    if "wander_cost" in block:  # explained sample by sample, a wander across blocks of time (the four-flip)
        lines.append(f"  but its sums over blocks of time wander beyond white noise (family p-value "
                     f"{block['block_test']['p_value']:.4g} <= {block['block_test']['threshold']:g}): the sigmas are widened for it")
        lines += cost_lines(block["wander_cost"], "wander")
    return "\n".join(lines)


def cost_lines(cost: dict | None, what: str = "unexplained") -> list[str]:
    """Report lines of what an unexplained residual costs (``unexplained_cost``; ``what``: the words that name the
    structure, "wander" for the four-flip's ``wander_cost``), none without one."""
    if not cost:
        return []
    lines = []
    if "direction_deg" in cost:
        sig = cost.get("direction_sigma_deg", {})
        lines.append(f"  {what} cost: direction sigmas widened by " + ", ".join(
            f"{name} {v:.3f} deg" + (f" ({sig[name]['naive']:.3f} -> {sig[name]['widened']:.3f})" if name in sig else "")
            for name, v in cost["direction_deg"].items()))
    if "hard_iron" in cost:
        # "stated", not "widened", when any stated sigma is under the naive (a walk modelled: see below)
        verb = "stated" if any(v["widened"] < v["naive"] for v in cost["hard_iron"].values()) else "widened"
        lines.append(f"  {what} cost: hard-iron sigmas {verb} " + ", ".join(
            f"{axis} {v['naive']:.3g} -> {v['widened']:.3g}" for axis, v in cost["hard_iron"].items()))
        if any(v["widened"] < v["naive"] and "noise_only" in v for v in cost["hard_iron"].values()):
            lines.append("      (under the naive where its chi-square scale counted the walk the blocks model as white "
                         "noise; the noise alone: " + ", ".join(
                             f"{axis} {v['noise_only']:.3g}" for axis, v in cost["hard_iron"].items()) + ")")
    if "heading_deg" in cost:
        h = cost.get("heading_sigma_deg")
        if h and h["widened"] < h["naive"]:  # restated under the naive (the hard-iron line above says why)
            lines.append(f"  {what} cost at runtime: heading sigma of a level housing {h['naive']:.3f} -> "
                         f"{h['widened']:.3f} deg RMS over headings (under the naive, as the hard iron's)")
        else:
            lines.append(f"  {what} cost at runtime: heading sigma of a level housing widened by "
                         f"{cost['heading_deg']:.3f} "
                         "deg" + (f" ({h['naive']:.3f} -> {h['widened']:.3f} deg RMS over headings)" if h else ""))
    if "method" in cost:
        lines.append(f"      ({cost['method']})")
    return lines
