"""Fits on hostile data: a law that cannot be fitted is a FitError, in a comparison a record.

Issue 11 item 3: an auxiliary fit never takes down an analysis. The fits work in dimensionless,
bounded log-parameters, so no data overflow them; what no law can describe is reported.
"""

import math

import numpy as np
import pytest

from microball_ros.core import friction
from microball_ros.core.errors import FitError, InputError
from microball_ros.core.friction import STATIC_LAWS, Langevin, compare_laws, fit_law

A, ALPHA = 1.2, 110.0


def _samples(law, v_max=0.009, n=600, noise=0.02, seed=3):
    rng = np.random.default_rng(seed)
    v = v_max * np.sin(rng.uniform(0, 2 * math.pi, n))
    return v, law.acceleration(v) + noise * rng.standard_normal(n)


def _assert_each_entry_ok_or_explained(entries):
    assert sorted(entry.name for entry in entries) == sorted(STATIC_LAWS)
    for entry in entries:
        if entry.ok:
            assert math.isfinite(entry.aic) and math.isfinite(entry.rmse) and entry.error is None
            assert all(0 < value < math.inf for value in entry.params.values())
        else:
            assert entry.error and '\n' not in entry.error
            assert entry.aic is None and entry.rmse is None and entry.params == {}


@pytest.mark.parametrize('hostile, reason', [
    (lambda v, a: (v, -a), 'does not oppose'),           # friction pushing along the sliding
    (lambda v, a: (v, np.zeros_like(a)), 'zero'),         # no friction at all
])
def test_a_law_fit_on_hostile_data_is_a_failure_record_not_an_exception(hostile, reason):
    v, a = hostile(*_samples(Langevin(A, ALPHA)))
    for name in STATIC_LAWS:
        with pytest.raises(FitError, match=reason):
            friction.fit_least_squares(v, a, name)
        entry = fit_law(v, a, name)
        assert not entry.ok and entry.fit is None and reason in entry.error
        assert entry.error.startswith(f'{name}: ')
    entries = compare_laws(v, a)
    assert not any(entry.ok for entry in entries)
    _assert_each_entry_ok_or_explained(entries)


@pytest.mark.parametrize('level', [1e300, 1e306])
def test_an_overflowing_record_gives_records_not_exceptions(level):
    # Forces near the largest double: the bounds reach past it (1e306 * 1e6 overflows), so a law
    # may fail, but only ever as a record with its reason.
    v, a = _samples(Langevin(A, ALPHA))
    entries = compare_laws(v, level * np.sign(a))
    _assert_each_entry_ok_or_explained(entries)
    for entry in entries:
        if not entry.ok:
            with pytest.raises(FitError):
                friction.fit_least_squares(v, level * np.sign(a), entry.name)


@pytest.mark.parametrize('scale', [1e-150, 1e-6, 1e6, 1e150])
def test_fits_are_the_same_for_data_in_any_units_and_never_overflow(scale):
    # Langevin and viscous laws are covariant: v -> k v, a -> k a gives A -> k A, alpha -> alpha/k,
    # c -> c. The Coulomb-type laws have a fixed smoothing velocity: they only must not raise.
    v, a = _samples(Langevin(A, ALPHA), v_max=0.03)
    reference = {entry.name: entry for entry in compare_laws(v, a)}
    with np.errstate(over='raise', invalid='raise'):
        scaled = {entry.name: entry for entry in compare_laws(scale * v, scale * a)}
    _assert_each_entry_ok_or_explained(list(scaled.values()))
    langevin = scaled['langevin']
    assert langevin.params['A'] == pytest.approx(scale * reference['langevin'].params['A'],
                                                 rel=1e-6)
    assert langevin.params['alpha'] == pytest.approx(
        reference['langevin'].params['alpha'] / scale, rel=1e-6)
    assert scaled['viscous'].params['c'] == pytest.approx(reference['viscous'].params['c'],
                                                          rel=1e-9)
    assert langevin.rmse == pytest.approx(scale * reference['langevin'].rmse, rel=1e-6)
    # AIC shifts by n ln(k^2) with the units of the residuals.
    assert langevin.aic == pytest.approx(reference['langevin'].aic + len(v) * math.log(
        scale ** 2), abs=1e-6 * abs(reference['langevin'].aic))


def test_degenerate_data_fit_within_the_bounds_and_report_open_intervals():
    # Stribeck on purely viscous data: Fs, Fc and vs are not determined. The fit must stay in
    # its bounded domain (every parameter positive and finite) and say so with open intervals.
    v, a = _samples(friction.Viscous(44.0), v_max=0.005, noise=0.05)
    entry = fit_law(v, a, 'stribeck')
    assert entry.ok, entry.error
    scales = {'Fc': np.quantile(np.abs(a), 0.95), 'Fs': np.quantile(np.abs(a), 0.95),
              'vs': np.abs(v).max(), 'c': np.quantile(np.abs(a), 0.95) / np.abs(v).max()}
    for name, value in entry.params.items():
        ratio = value / scales[name]
        assert math.exp(-friction.LOG_BOUND) * (1 - 1e-9) <= ratio
        assert ratio <= math.exp(friction.LOG_BOUND) * (1 + 1e-9)
    assert not entry.fit.identifiable


def test_input_that_is_not_fit_data_still_raises_input_error():
    with pytest.raises(InputError, match='finite'):
        fit_law([0.1, np.nan, 0.3, 0.4], [1, 2, 3, 4], 'viscous')
    with pytest.raises(InputError, match='unknown law'):
        fit_law([0.1, 0.2, 0.3], [1, 2, 3], 'magic')


def test_comparison_profiles_only_the_named_laws_and_gives_the_others_wald_intervals():
    # Issue 13: profiles of five laws were most of an hour-long record's analysis. The named law
    # keeps its profile intervals exactly; the others get Wald intervals of the log-parameters,
    # the same fits (parameters, AIC) and, for the viscous law (linear: its profile interval is
    # exact), an interval within 1 % of the profile one at this noise.
    v, a = _samples(Langevin(A, ALPHA), v_max=0.02, noise=0.01)
    full = {entry.name: entry for entry in compare_laws(v, a)}
    quick = {entry.name: entry for entry in compare_laws(v, a, profile=('langevin',))}
    assert quick['langevin'].ci95 == full['langevin'].ci95
    for name in STATIC_LAWS:
        assert quick[name].aic == full[name].aic and quick[name].params == full[name].params
    (lo, hi), (plo, phi) = quick['viscous'].ci95['c'], full['viscous'].ci95['c']
    c = quick['viscous'].params['c']
    assert lo < c < hi and lo > 0 and math.isfinite(hi)
    assert abs(lo - plo) < 0.01 * (phi - plo) and abs(hi - phi) < 0.01 * (phi - plo)
    with pytest.raises(InputError, match='intervals'):
        friction.fit_least_squares(v, a, 'viscous', intervals='bootstrap')
