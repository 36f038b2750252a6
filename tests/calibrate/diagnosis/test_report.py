"""The report's lines of what an unexplained residual costs: calibrate/diagnosis/report.py."""

from calibrate.diagnosis.report import cost_lines


def test_hard_iron_sigmas_under_the_naive_are_said_stated_not_widened():
    """A walk modelled can state a hard-iron sigma under the naive one: the line says "stated" (with the noise
    alone beside it), never "widened x a -> b" with b < a; a plain widening says "widened"."""
    under = {"hard_iron": {"mx": {"naive": 0.5, "widened": 0.3, "noise_only": 0.2},
                           "my": {"naive": 0.5, "widened": 0.6, "noise_only": 0.2}}}
    text = "\n".join(cost_lines(under))
    assert "hard-iron sigmas stated mx 0.5 -> 0.3, my 0.5 -> 0.6" in text and "widened" not in text.split("\n")[0]
    assert "the noise alone: mx 0.2, my 0.2" in text
    over = {"hard_iron": {"mx": {"naive": 0.5, "widened": 0.7}, "my": {"naive": 0.5, "widened": 0.6}}}
    assert cost_lines(over)[0] == "  unexplained cost: hard-iron sigmas widened mx 0.5 -> 0.7, my 0.5 -> 0.6"


def test_a_wander_cost_is_named_as_a_wander_not_as_unexplained():
    """The four-flip's wander_cost (an explained fit widened for a wander across blocks of time) shares the
    unexplained cost's lines under its own name, and the diagnosis's report says why it was widened."""
    from calibrate.diagnosis.report import format_diagnosis

    cost = {"direction_deg": {"a": 0.02}, "direction_sigma_deg": {"a": {"naive": 0.01, "widened": 0.0224}},
            "heading_deg": 0.03, "heading_sigma_deg": {"naive": 0.02, "widened": 0.036}}
    assert cost_lines(cost, "wander")[0] == "  wander cost: direction sigmas widened by a 0.020 deg (0.010 -> 0.022)"
    block = {"noise_floor": 1.0, "steps": [{"model": "base", "residual_rms": 1.0}], "effects": [],
             "residual_rms_before": 1.0, "residual_rms_after": 1.0,
             "unexplained": False, "block_test": {"p_value": 0.001, "threshold": 0.01}, "wander_cost": cost}
    text = format_diagnosis(block)
    assert "wander beyond white noise (family p-value 0.001 <= 0.01)" in text
    assert "wander cost at runtime: heading sigma of a level housing widened by 0.030 deg" in text
    assert "unexplained cost" not in text
