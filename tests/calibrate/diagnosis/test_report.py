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
