"""Every kind's effects speak one protocol (calibrate.effects.Effect), with the shared time and temperature forms."""

import numpy as np
import pytest

from calibrate.diagnosis.offsets import FORMS as OFFSET_FORMS
from calibrate.effects import (Basis, Effect, EffectForm, Recorded, TemperatureForm, TimeForm, WarmUpForm, settled,
                               time_powers, warm_up_tau_s)
from calibrate.fourflip.effects import VARIANTS as FOURFLIP_FORMS
from calibrate.installation.diagnosis import FORMS as INSTALLATION_FORMS
from calibrate.tumble.diagnosis import TUMBLE_FORMS

SPEC_NAMES = {"nonlinear_response", "encoder_error", "offset_drift", "platform_field", "flip_error", "temperature",
              "gain_drift", "turntable_zero"}
"""SPEC section 4's vocabulary and the names we added when we modelled more (``turntable_zero``: docs/calibration.md)."""
KINDS = {"fourflip": FOURFLIP_FORMS, "offsets": OFFSET_FORMS, "tumble": TUMBLE_FORMS,
         "installation": INSTALLATION_FORMS}
EVERY_FORM = [(kind, e) for kind, forms in KINDS.items() for name, group in forms.items() for e in group]


@pytest.mark.parametrize("kind, effect", EVERY_FORM, ids=[f"{k}-{e.label}" for k, e in EVERY_FORM])
def test_every_form_is_an_effect_with_a_spec_name_and_a_parameter_count_in_channels(kind, effect):
    assert isinstance(effect, Effect) and isinstance(effect, EffectForm)
    assert effect.name in SPEC_NAMES and effect.name in KINDS[kind] and effect in KINDS[kind][effect.name]
    assert effect.label == (f"{effect.name} ({effect.form})" if effect.form else effect.name)
    # one signature: the count grows with the channels unless the block is shared (encoder, flips, platform)
    counts = [effect.n_params(c) for c in (1, 2, 3, 6)]
    assert all(isinstance(n, int) and n > 0 for n in counts) and counts == sorted(counts)
    for c in (2, 3):
        points = effect.score_points(c)
        assert points and all(p.shape == (effect.n_params(c),) for p in points)


@pytest.mark.parametrize("kind, effect", EVERY_FORM, ids=[f"{k}-{e.label}" for k, e in EVERY_FORM])
def test_time_and_temperature_forms_say_why_a_recording_cannot_show_them(kind, effect):
    t_s, temp_c = np.linspace(0.0, 600.0, 50), np.linspace(20.0, 30.0, 50)
    assert effect.applicable(Recorded(t_s, temp_c)) is None
    if isinstance(effect, TimeForm):
        assert effect.applicable(Recorded(None, temp_c)) == "the recording has no t_s column"
        assert effect.applicable(Recorded(np.zeros(50), temp_c)) == "t_s never changes"
    if isinstance(effect, TemperatureForm):
        assert effect.applicable(Recorded(t_s, None)) == "the recording has no temp_c column"
        assert effect.applicable(Recorded(t_s, np.full(50, 21.0))) == "temp_c varies by less than 0.5 degC"
    if not isinstance(effect, (TimeForm, TemperatureForm)) and effect.name != "nonlinear_response":
        assert effect.applicable(Recorded()) is None


def test_the_time_and_temperature_effects_are_the_shared_forms_in_every_kind():
    for kind, forms in KINDS.items():
        for effect in forms.get("offset_drift", ()) + forms.get("gain_drift", ()):
            assert isinstance(effect, TimeForm), (kind, effect.label)
        for effect in forms.get("temperature", ()):
            assert isinstance(effect, TemperatureForm), (kind, effect.label)
    warm_ups = [e for forms in KINDS.values() for e in forms.get("offset_drift", ()) if isinstance(e, WarmUpForm)]
    assert len(warm_ups) == 3  # four-flip, known-input fits, tumble: one form written once


def test_the_tumble_cubic_needs_both_half_axes():
    cubic = TUMBLE_FORMS["nonlinear_response"][0]
    assert cubic.applicable(Recorded()) is None
    assert "never along +Z" in cubic.applicable(Recorded(missing=("+Z",)))


def test_the_basis_is_zero_at_the_reference_and_one_a_span_away():
    t_s, temp_c = np.array([5.0, 65.0, 125.0]), np.array([19.0, 20.0, 24.0])
    basis = Basis.of(t_s, temp_c)
    assert basis.t_ref_s == 5.0 and basis.session_s == 120.0 and basis.temp_ref_c == 21.0 and basis.temp_span_c == 5.0
    np.testing.assert_allclose(basis.tau(t_s), [0.0, 0.5, 1.0])
    np.testing.assert_allclose(basis.d(temp_c), [-0.4, -0.2, 0.6])
    np.testing.assert_allclose(time_powers(basis.tau(t_s), 3), [[0, 0, 0], [0.5, 0.25, 0.125], [1, 1, 1]])
    neutral = Basis.of(None, None)
    assert (neutral.t_ref_s, neutral.session_s, neutral.temp_ref_c, neutral.temp_span_c) == (0.0, 1.0, 0.0, 1.0)


def test_the_warm_up_settles_and_its_time_constant_is_clipped():
    tau_s = warm_up_tau_s(100.0, np.log(0.5))
    assert tau_s == pytest.approx(50.0)
    np.testing.assert_allclose(settled(np.array([0.0, 50.0, 1e6]), 0.0, tau_s), [0.0, 1 - np.exp(-1.0), 1.0])
    assert warm_up_tau_s(100.0, 50.0) == pytest.approx(100.0 * np.exp(3.0))
    assert warm_up_tau_s(100.0, -50.0) == pytest.approx(100.0 * np.exp(-6.0))
