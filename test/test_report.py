"""`microball analyze --report`: the figure set, the notes, the statements, the CSV contract.

Figures are checked as files (PNG, sensible size); what they must say is checked through the
functions that build it (figure_notes, summary_lines, compensation), not through pixels.
"""

import csv
from dataclasses import replace
import json
import math
import pathlib

import numpy as np
from PIL import Image
import pytest

from microball_ros.app import analysis, report
from microball_ros.core import bench
from microball_ros.io.positions_csv import read_positions_csv, write_positions_csv

SAMPLE_BAG = pathlib.Path(__file__).resolve().parent.parent / 'bags' / 'paper_sample'
FIGURE_NAMES = ['positions.png', 'derivatives.png', 'methods.png', 'model.png',
                'compensation.png', 'validation.png']
LAG = 0.035  # s, the 'lagged' scenario's first-order lag of the Langevin friction


def _simulated(tmp_path_factory, scenario, duration=40):
    path = tmp_path_factory.mktemp(scenario) / 'positions.csv'
    record = bench.simulate(bench.get_scenario(scenario), duration)
    write_positions_csv(str(path), record.to_columns())
    return analysis.analyze_record(read_positions_csv(str(path)), source=str(path))


@pytest.fixture(scope='module')
def paper(tmp_path_factory):
    return _simulated(tmp_path_factory, 'paper')


@pytest.fixture(scope='module')
def lagged(tmp_path_factory):
    return _simulated(tmp_path_factory, 'lagged')


@pytest.fixture(scope='module')
def sample_bag_result():
    record = analysis.load_positions(str(SAMPLE_BAG))
    exposure = analysis.recorded_exposure(str(SAMPLE_BAG))
    return analysis.analyze_record(record, exposure=exposure, source=str(SAMPLE_BAG))


def _check_report(result, directory):
    paths = report.write_report(result, str(directory))
    names = [pathlib.Path(p).name for p in paths]
    assert names == ['estimates.csv', 'estimates.units.json', 'summary.txt', *FIGURE_NAMES]
    for name in FIGURE_NAMES:
        path = directory / name
        assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
        with Image.open(path) as image:
            width, height = image.size
        assert 800 <= width <= 1400 and 350 <= height <= 1000, (name, image.size)
        assert path.stat().st_size < 150_000, name
    return paths


def test_every_figure_is_written_for_a_csv(paper, tmp_path):
    _check_report(paper, tmp_path / 'report')


def test_every_figure_is_written_for_a_bag(sample_bag_result, tmp_path):
    _check_report(sample_bag_result, tmp_path / 'report')


def test_estimates_csv_keeps_the_contract_header_and_units_go_beside_it(paper, tmp_path):
    directory = tmp_path / 'report'
    report.write_report(paper, str(directory))
    with open(directory / 'estimates.csv', newline='') as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ['time', 'relative_velocity', 'slider_acceleration']
    values = np.array(rows[1:], dtype=float)
    est = paper.estimate
    assert values.shape == (len(est.time), 3)
    # Written with repr: the numbers read back exactly.
    assert np.array_equal(values, np.column_stack([est.time, est.velocity, est.acceleration]))
    units = json.loads((directory / 'estimates.units.json').read_text())
    assert list(units['columns']) == rows[0]
    assert [units['columns'][name]['unit'] for name in rows[0]] == ['s', 'm/s', 'm/s^2']
    summary = (directory / 'summary.txt').read_text()
    assert 'estimates.csv columns: time (s;' in summary
    assert 'relative_velocity (m/s;' in summary and 'slider_acceleration (m/s^2;' in summary


def test_no_notes_for_a_memoryless_record_without_warnings(paper):
    assert paper.pipeline.memory_verdict == 'memoryless' and paper.warnings == ()
    assert report.figure_notes(paper) == []


def test_the_notes_carry_every_warning_code_and_the_memory_verdict(lagged):
    pipe = lagged.pipeline
    assert pipe.memory_verdict == 'memory'
    codes = [code for code, _ in lagged.warnings]
    assert 'degenerate' in codes and codes
    notes = report.figure_notes(lagged)
    assert notes[0].startswith('MEMORY FOUND')
    assert f'{pipe.loop.statistic:+.4f} +- {pipe.loop.uncertainty:.4f} rad' in notes[0]
    assert notes[1:] == [f'[{code}] {message}' for code, message in lagged.warnings]


def test_notes_follow_the_warnings_given(paper):
    warned = replace(paper, pipeline=replace(paper.pipeline, warnings=(
        ('near-nyquist', '5.00 samples per stator period'), ('gaps', '3 frames dropped'))))
    assert report.figure_notes(warned) == ['[near-nyquist] 5.00 samples per stator period',
                                           '[gaps] 3 frames dropped']
    undecided = replace(paper, pipeline=replace(
        paper.pipeline, loop=replace(paper.pipeline.loop, verdict='undetermined')))
    assert report.figure_notes(undecided)[0].startswith('MEMORY UNDETERMINED')


def _with_scores(result, scores):
    """Return result with its fitted laws given (name, aic, bic), in that (AIC) order."""
    entries = {entry.name: entry for entry in result.comparison if entry.ok}
    comparison = tuple(replace(entries[name], fit=replace(entries[name].fit, aic=aic, bic=bic))
                       for name, aic, bic in scores)
    return replace(result, pipeline=replace(result.pipeline, comparison=comparison))


def _ranking(result):
    lines = [line for line in analysis.summary_lines(result) if line.startswith('static laws')]
    assert len(lines) == 1
    return lines[0]


def test_a_small_aic_difference_is_reported_as_a_tie(paper):
    tied = _with_scores(paper, [('stribeck', -100.0, -80.0), ('langevin', -99.5, -85.0),
                                ('viscous', -50.0, -45.0)])
    assert _ranking(tied) == ('static laws: stribeck and langevin tie by AIC (difference 0.5; '
                              '2 or less is no verdict); BIC prefers langevin')
    assert 'best' not in _ranking(tied)


def test_three_laws_within_two_tie_and_a_clear_gap_is_a_verdict(paper):
    # A nested law with the same fit is 2.0 behind (its extra parameter's penalty): a tie.
    three = _with_scores(paper, [('viscous', -10.0, -5.0), ('langevin', -8.1, -1.0),
                                 ('coulomb_viscous', -8.0, -1.1), ('coulomb', 20.0, 30.0)])
    assert _ranking(three) == ('static laws: viscous, langevin and coulomb_viscous tie by AIC '
                               '(differences 1.9, 2.0; 2 or less is no verdict); BIC prefers '
                               'viscous')
    clear = _with_scores(paper, [('langevin', -100.0, -90.0), ('stribeck', -97.9, -93.0)])
    assert _ranking(clear) == ('static laws: best by AIC langevin (next stribeck, AIC '
                               'difference 2.1); BIC prefers stribeck')
    agreed = _with_scores(paper, [('langevin', -100.0, -90.0), ('stribeck', -80.0, -70.0)])
    assert _ranking(agreed).endswith('AIC difference 20.0); BIC agrees')


def test_the_memory_line_states_the_verdict_with_its_statistic(lagged):
    loop = lagged.loop
    # A first-order lag tau rotates the fundamentals by atan(w tau) (core.memory.LoopTest).
    assert loop.statistic == pytest.approx(math.atan(2 * math.pi * 2.95 * LAG), abs=0.02)
    line = analysis.summary_lines(lagged)[1]
    assert line.startswith(f'memory verdict: memory: loop statistic {loop.statistic:+.4f} +- '
                           f'{loop.uncertainty:.4f} rad (1 sigma')


def test_a_degenerate_fit_is_reported_as_its_viscous_limit(lagged):
    c, (lo, hi) = lagged.pipeline.viscous_limit
    lines = analysis.summary_lines(lagged)
    model = [line for line in lines if line.startswith('Langevin model')]
    assert model == [f'Langevin model degenerate: only its viscous limit is determined, c = '
                     f'A alpha / 3 = {c:.4g} 1/s [{lo:.4g}, {hi:.4g}]; A and alpha separately '
                     f'are not; rmse {lagged.fit.rmse:.3g} m/s^2']
    assert not any(line.startswith('low-velocity slope') for line in lines)


def test_the_csv_ground_truth_is_the_true_columns(paper):
    truth = report.ground_truth(paper)
    assert truth is not None and truth['source'] == 'the CSV true_* columns'
    window = paper.window
    assert np.array_equal(truth['time'], window.time)
    assert np.array_equal(truth['relative_velocity'], window.extra['true_relative_velocity'])


def test_a_bag_ground_truth_comes_from_bench_ground_truth(sample_bag_result):
    truth = report.bag_ground_truth(str(SAMPLE_BAG))
    assert len(truth['time']) == 600 and np.all(np.diff(truth['time']) > 0)
    window = sample_bag_result.window
    matched = report.truth_at(truth, window.time, 'relative_velocity',
                              sample_bag_result.sample_period)
    assert np.all(np.isfinite(matched))
    # The recorded truth is the motion the tracked positions sample: v_rel's amplitude there
    # is the stroke 1.2 mm at 2.95 Hz times the slider's relative motion, about 9 mm/s.
    assert np.max(np.abs(matched)) == pytest.approx(0.009, rel=0.1)


def test_compensation_against_the_bag_ground_truth(sample_bag_result):
    _, _, _, reference, errors = report.compensation(sample_bag_result)
    assert np.count_nonzero(np.isfinite(reference)) > 500
    # Without stage 3 the velocity keeps the centre difference's factor sin(wD)/(wD) and the
    # exposure's averaging sin(wT/2)/(wT/2) (T = 1/60 s, as recorded): about 6.6 % low.
    w, dt, exposure = 2 * math.pi * 2.95, 1 / 30, 1 / 60
    shrink = (math.sin(w * dt) / (w * dt)) * (math.sin(w * exposure / 2) / (w * exposure / 2))
    assert errors['without stage 3'] == pytest.approx(1 - shrink, abs=0.01)
    assert errors['with stage 3'] < 0.01


def test_a_csv_without_ground_truth_draws_without_it(paper, tmp_path):
    bare = replace(paper, window=replace(paper.window, extra={}))
    assert report.ground_truth(bare) is None
    _, _, _, reference, errors = report.compensation(bare)
    assert reference is None and errors == {}
    report.figure_compensation(bare, str(tmp_path / 'compensation.png'))
    assert (tmp_path / 'compensation.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_a_report_without_a_model_still_writes_every_figure(paper, tmp_path):
    # A failed Langevin fit (fit-failed) leaves no curve, residuals or validation to draw.
    failed = replace(paper, pipeline=replace(
        paper.pipeline, fit=None, validation=None, viscous_limit=None,
        warnings=(('fit-failed', 'the Langevin law cannot be fitted: no convergence'),)))
    _check_report(failed, tmp_path / 'report')
    assert analysis.summary_lines(failed)[2] == 'Langevin model: not fitted (see warnings)'
    assert report.figure_notes(failed) == [
        '[fit-failed] the Langevin law cannot be fitted: no convergence']
