"""Every bad input a lab plausibly has: a correct result, or one clean line and exit 2.

Each case runs the `microball` command as a user does (a process), and checks the exit status
and that stderr is exactly one line naming the problem in the user's terms (no traceback, no
library message, no progress line before it).
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

SAMPLE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'bags',
                      'paper_sample')


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, '-m', 'microball_ros.cli', *args],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def _one_line(result, *words):
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1, result.stderr
    assert 'Traceback' not in result.stderr
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def _sine_csv(path, n=300, time_scale=1.0, position_scale=1.0, bom=False):
    t = np.arange(n) / 30.0
    x = 1.2e-3 * np.sin(2 * np.pi * 2.95 * t)
    rows = ['time,stator_position,slider_position']
    rows += [f'{float(a) * time_scale!r},{float(b) * position_scale!r},'
             f'{0.9 * float(b) * position_scale!r}' for a, b in zip(t, x, strict=True)]
    text = '\r\n'.join(rows) + '\r\n'
    path.write_bytes(text.encode('utf-8-sig' if bom else 'utf-8'))
    return str(path)


def test_time_in_milliseconds_is_named(tmp_path):
    path = _sine_csv(tmp_path / 'ms.csv', time_scale=1e3)
    _one_line(_run('analyze', path), path, 'look like milliseconds', 'seconds')


def test_positions_in_millimetres_are_named(tmp_path):
    path = _sine_csv(tmp_path / 'mm.csv', position_scale=1e3)
    _one_line(_run('analyze', path), path, 'looks like millimetres', 'metres')


def test_a_video_given_to_analyze_is_named_with_the_command_that_reads_it(tmp_path):
    video = tmp_path / 'paper.mkv'
    video.write_bytes(b'\x1a\x45\xdf\xa3' + bytes(range(256)) * 8)
    _one_line(_run('analyze', str(video)), 'paper.mkv', 'Matroska', 'microball track')


def test_an_excel_csv_utf8_with_byte_order_mark_and_crlf_is_read(tmp_path):
    path = _sine_csv(tmp_path / 'excel.csv', bom=True)
    result = _run('analyze', path, '--json', str(tmp_path / 'a.json'))
    assert result.returncode == 0, result.stderr
    assert json.loads((tmp_path / 'a.json').read_text())['samples_total'] == 300


def test_a_nan_cell_names_the_file_row_and_column(tmp_path):
    path = tmp_path / 'nan.csv'
    path.write_text('time,stator_position,slider_position\n0,1e-3,1e-3\n0.033,nan,1e-3\n')
    _one_line(_run('analyze', str(path)), str(path), 'row 3', 'stator_position', 'nan')


def test_a_record_too_short_to_analyse_says_so(tmp_path):
    path = _sine_csv(tmp_path / 'six.csv', n=6)
    line = _one_line(_run('analyze', str(path)), str(path))
    assert 'need' in line or 'too short' in line or 'only' in line


def test_simulating_more_than_memory_holds_is_refused_before_it_starts(tmp_path):
    _one_line(_run('simulate', '--duration', '1e9', '--output', str(tmp_path / 'x.csv')),
              '--duration', 'memory')
    assert not (tmp_path / 'x.csv').exists()


def test_render_to_a_text_file_is_refused_without_opencv_noise(tmp_path):
    _one_line(_run('render', '--duration', '1', '--output', str(tmp_path / 'x.txt')),
              'x.txt', '.mkv')


def test_the_same_roi_for_slider_and_stator_is_refused(tmp_path):
    video = str(tmp_path / 'r.mkv')
    assert _run('render', '--duration', '1', '--output', video).returncode == 0
    _one_line(_run('track', video, '--slider-roi', '137,75,479,62', '--stator-roi',
                   '137,75,479,62', '--meters-per-pixel', '5.88e-6', '--output',
                   str(tmp_path / 'p.csv')), 'slider and stator ROIs overlap')


@pytest.mark.ros
def test_an_experiment_too_short_for_a_result_exits_2():
    # A long command shows its progress while it works; the error is its last line.
    result = _run('experiment', '--duration', '1', '--speed', '1.5')
    assert result.returncode == 2 and 'Traceback' not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert 'no complete analysis window' in lines[-1]
    assert len(lines) == len(set(lines)), 'a progress line repeated'


def test_a_mcap_file_and_its_bag_directory_give_the_same_answer(tmp_path):
    mcap = os.path.join(SAMPLE, 'paper_sample_0.mcap')
    results = []
    for source, name in ((SAMPLE, 'dir.json'), (mcap, 'file.json')):
        run = _run('analyze', source, '--json', str(tmp_path / name))
        assert run.returncode == 0, run.stderr
        results.append((run.stdout, json.loads((tmp_path / name).read_text())))
    (dir_out, dir_json), (file_out, file_json) = results
    dir_json.pop('source'), file_json.pop('source')
    assert dir_json == file_json
    def printed(out, source):  # the summary, to the last printed digit (not the file names)
        return [line.replace(source, 'BAG') for line in out.splitlines()
                if not line.startswith('wrote ')]

    assert printed(dir_out, SAMPLE) == printed(file_out, mcap)
