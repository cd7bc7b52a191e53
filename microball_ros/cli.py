"""The ``microball`` command line (contract: docs/design.md section 5).

Every sub-command validates its input; a problem the user can fix (a MicroballError) is one
line on stderr and exit status 2, Ctrl-C is 130, and anything else is a bug with its traceback
and exit status 1. The work itself lives in app/ and below; this file parses and prints.
"""

import argparse
import json
import os
import sys

from microball_ros.app.terminal import Progress, pause_on_space
from microball_ros.core.errors import InputError, MicroballError

EXIT_BAD_INPUT = 2
EXIT_DIFFERS = 3  # microball reprocess: the outputs differ from the recorded ones
EXIT_INTERRUPTED = 130

# FFmpeg inside OpenCV prints its own parser complaints about a broken video; our one-line
# error says it better.
os.environ.setdefault('OPENCV_FFMPEG_LOGLEVEL', '-8')


class CliError(InputError):
    """Bad input detected by the CLI itself; the message is shown as one line."""


def _positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a number') from None
    if not value > 0 or value == float('inf'):
        raise argparse.ArgumentTypeError(f'{text!r} must be a positive finite number')
    return value


def _non_negative_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a number') from None
    if not 0 <= value < float('inf'):
        raise argparse.ArgumentTypeError(f'{text!r} must be a finite number >= 0')
    return value


def _gamma(text):
    return 0.0 if text == 'auto' else _positive_float(text)


def _fraction(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a number') from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f'{text!r} must be in [0, 1)')
    return value


_progress = Progress()

# Work that would not fit in memory is refused before it starts (bytes of the arrays kept).
MAX_SIMULATED_SAMPLES = 10_000_000   # simulate: about 1 GB of columns (92 h at 30 fps)


def cmd_simulate(args):
    """Simulate the bench (no camera) and write its positions and ground truth to CSV."""
    from microball_ros.core import bench
    from microball_ros.io.positions_csv import write_positions_csv

    scenario = bench.get_scenario(args.scenario, **({'seed': args.seed}
                                                    if args.seed is not None else {}))
    samples = args.duration * scenario.frame_rate
    if samples > MAX_SIMULATED_SAMPLES:
        raise CliError(f'--duration {args.duration:g} s is {samples:.3g} samples at '
                       f'{scenario.frame_rate:g} fps, more than {MAX_SIMULATED_SAMPLES:,} '
                       f'({MAX_SIMULATED_SAMPLES / scenario.frame_rate / 3600:.0f} h) fit in '
                       'memory; simulate shorter records')
    _progress(f'simulating {args.duration:g} s of scenario {args.scenario!r} ...')
    record = bench.simulate(scenario, args.duration)
    columns = record.to_columns()
    if not args.ground_truth:
        columns = {k: v for k, v in columns.items() if not k.startswith('true_')}
    write_positions_csv(args.output, columns)
    print(f'wrote {len(record.time)} samples at {scenario.frame_rate:g} fps to {args.output}')
    return 0


def cmd_analyze(args):
    """Analyse positions: derivatives, memory test, Langevin fit, validation."""
    from microball_ros.app.analysis import (
                                        analyze_record,
                                        load_positions,
                                        recorded_exposure,
                                        summary_lines,
    )

    record = load_positions(args.input, **_frame_tracking(args), progress=_progress)
    exposure = args.exposure
    if exposure is None:
        exposure = recorded_exposure(args.input)
        if exposure is not None:
            _progress(f'exposure {exposure:.6g} s, as recorded for the estimator')
    _progress(f'analysing {len(record.time)} samples from {args.input} ({args.method}) ...')
    result = analyze_record(record, method=args.method, epsilon=args.epsilon,
                            fit_epsilon=args.fit_epsilon, exposure=exposure or 0.0,
                            source=args.input)
    for line in summary_lines(result):
        print(line)
    if args.json:
        directory = os.path.dirname(os.path.abspath(args.json))
        os.makedirs(directory, exist_ok=True)
        with open(args.json, 'w') as handle:
            json.dump(result.to_json(), handle, indent=2, allow_nan=False, sort_keys=True)
            handle.write('\n')
        print(f'wrote {args.json}')
    if args.report:
        from microball_ros.app.report import write_report

        _progress(f'drawing figures into {args.report} ...')
        for path in write_report(result, args.report):
            print(f'wrote {path}')
    return 0


def _roi(text):
    from microball_ros.core.tracking import parse_roi

    try:
        return parse_roi(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _track_progress(done, total):
    of = f' of {total}' if total else ''
    _progress(f'tracked {done}{of} frames')


def _frame_tracking_arguments(parser):
    group = parser.add_argument_group(
        'a bag with only camera frames', 'it is tracked first, with these values, else those '
        'its recording kept (ROIs neither gives are detected in the first frames)')
    group.add_argument('--slider-roi', type=_roi, metavar='X,Y,W,H',
                       help='region of the slider mark over its whole travel, px')
    group.add_argument('--stator-roi', type=_roi, metavar='X,Y,W,H',
                       help='region of the stator mark over its whole travel, px')
    group.add_argument('--meters-per-pixel', type=_positive_float, metavar='M',
                       help='image scale along the bearing axis, m/px')


def _frame_tracking(args):
    return {'slider_roi': args.slider_roi, 'stator_roi': args.stator_roi,
            'meters_per_pixel': args.meters_per_pixel}


def cmd_track(args):
    """Track the slider and stator marks through a video and write the position CSV.

    With --preview, track only the first frames and draw the last one with the ROIs, the
    learned marks and the track (a check of the set-up before a long run).
    """
    import itertools

    from microball_ros.app.tracking import summary_lines
    from microball_ros.core.tracking import TrackerConfig, check_scale, draw_tracking
    from microball_ros.io.positions_csv import write_positions_csv
    from microball_ros.io.video import FrameSource, track_video

    check_scale(args.meters_per_pixel)
    if not os.path.exists(args.video):
        raise CliError(f'{args.video}: no such file or folder')
    if args.preview_frames < 1:
        raise CliError('--preview-frames must be at least 1')
    if args.output is None and args.preview is None:
        raise CliError('give --output FILE.csv (or --preview FILE.png)')
    config = TrackerConfig(polarity=args.polarity, method=args.method,
                           black_level=args.black_level, gamma=args.gamma)
    rois = {'slider': args.slider_roi, 'stator': args.stator_roi}
    source = FrameSource(args.video)
    max_frames = args.preview_frames if args.preview and not args.output else None
    result = track_video(source, rois, args.meters_per_pixel, fps=args.fps,
                         exposure=args.exposure, progress=_track_progress, config=config,
                         max_frames=max_frames)
    if args.preview:
        import cv2

        last = len(result.time) - 1
        frame = next(itertools.islice(iter(source), last, None))
        image = draw_tracking(frame, rois,
                              {n: result.position_px[n][last] for n in result.names},
                              {n: result.position_px[n] for n in result.names},
                              {n: result.polarity.get(n, '') for n in result.names})
        if not cv2.imwrite(args.preview, image):
            raise CliError(f'{args.preview}: cannot write the preview image')
        print(f'wrote {args.preview} (frame {last}; polarity: '
              f"slider {result.polarity.get('slider', '?')}, "
              f"stator {result.polarity.get('stator', '?')})")
    if args.output:
        columns = result.to_columns()
        write_positions_csv(args.output, columns)
        lost = {name: int(sum(1 for v in columns[f'{name}_position'] if v != v))
                for name in ('slider', 'stator')}
        print(f"wrote {len(columns['time'])} frames to {args.output} "
              f"(lost: slider {lost['slider']}, stator {lost['stator']})")
        for line in summary_lines(result, source, args.black_level):
            print(line)
    return 0


def cmd_render(args):
    """Render the simulated rig to a video, and print the track command that reads it."""
    from microball_ros.app.render import render_video

    rendered, codec = render_video(args.scenario, args.output, args.duration, seed=args.seed,
                                   lossless=args.lossless, progress=_progress)
    rois = {name: ','.join(str(v) for v in roi) for name, roi in rendered.rois.items()}
    config = rendered.config
    print(f'wrote {len(rendered.frames)} frames ({codec}) to {args.output}')
    print(f"track it with: microball track {args.output} --slider-roi {rois['slider']} "
          f"--stator-roi {rois['stator']} --meters-per-pixel {config.meters_per_pixel:.6g} "
          f'--exposure {config.exposure:.6g} --output positions.csv')
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (and a pointer to --help), exit status 2."""

    def error(self, message):
        """Print one line and exit with status 2."""
        self.exit(EXIT_BAD_INPUT, f'{self.prog}: error: {message} (see {self.prog} --help)\n')


def cmd_experiment(args):
    """Run the whole simulated rig, node by node over DDS, and print the identified model."""
    from microball_ros.app.experiment import NodeCrashed, run_experiment, summary_lines
    from microball_ros.core import bench

    if args.output and os.path.exists(args.output) and os.listdir(args.output):
        raise CliError(f'{args.output}: exists and is not empty; choose a new bag directory')
    bench.get_scenario(args.scenario)
    try:
        monitor = run_experiment(args.scenario, args.duration, args.speed, progress=_progress,
                                 output=args.output, domain_id=args.domain_id,
                                 params_file=args.params)
    except NodeCrashed as error:
        _progress.flush()
        print(f'microball experiment: {error}', file=sys.stderr)
        return 1
    lines = summary_lines(monitor, args.scenario)
    if not monitor.windows or not monitor.models:
        raise CliError(f'{lines[0]}' + (f' (the bag {args.output} was recorded)'
                                        if args.output else ''))
    for line in lines:
        print(line)
    if args.output:
        print(f'recorded every topic into {args.output}')
    return 0


def cmd_record(args):
    """Record topics to a bag until Ctrl-C (or --duration)."""
    from microball_ros.app.record import record

    def started():
        _progress(f'recording {", ".join(args.topics) if args.topics else "every topic"} '
                  f'into {args.output}; Ctrl-C stops')

    counts, lost = record(args.output, args.topics, args.duration, started)
    for topic in sorted(counts):
        print(f'{topic}: {counts[topic]} messages, {lost.get(topic, 0)} lost')
    return 0


def cmd_play(args):
    """Publish a bag's messages in recorded order."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from microball_ros.app.play import Player, use_lockstep_profile
    from microball_ros.io.bags.reader import open_bag

    bag = open_bag(args.bag)
    if args.lockstep:
        use_lockstep_profile()
    context = rclpy.Context()
    rclpy.init(context=context)
    player = restore_terminal = None
    try:
        player = Player(bag, topics=args.topics, clock=args.clock, context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(player)
        paused, restore_terminal = pause_on_space(_progress)
        total = sum(bag.topics[t].count for t in player.publishers_by_topic)
        _progress(f'playing {total} messages of {args.bag} at {args.rate:g}x'
                  f'{" lock-step" if args.lockstep else ""}'
                  f'{"; space pauses" if paused else ""}; Ctrl-C stops')
        while True:
            count = player.play(executor, rate=args.rate, start_offset=args.start_offset,
                                lockstep=args.lockstep, paused=paused,
                                progress=lambda n, t: _progress(f'played {n} of {total} '
                                                                f'messages, t = {t:.1f} s'))
            print(f'played {count} messages')
            if not args.loop:
                break
        player.destroy_node()
    except KeyboardInterrupt:
        print(f'stopped after {player.published if player else 0} messages')
    finally:
        if restore_terminal is not None:
            restore_terminal()
        if context.ok():
            rclpy.shutdown(context=context)
    return 0


def cmd_reprocess(args):
    """Replay a bag through fresh nodes, record their outputs, compare them with the bag's."""
    from microball_ros.app.experiment import NodeCrashed
    from microball_ros.app.reprocess import check, reprocess

    try:
        counts = reprocess(args.bag, args.output, progress=_progress,
                           tracking=_frame_tracking(args))
    except NodeCrashed as error:
        _progress.flush()
        print(f'microball reprocess: {error}', file=sys.stderr)
        return 1
    for topic in sorted(counts):
        print(f'{topic}: {counts[topic]} messages')
    print(f'wrote {args.output}')
    _progress('comparing the outputs with the recorded ones ...')
    result = check(args.bag, args.output)
    for line in result.platform_lines():
        print(line)
    print(result.verdict.line)
    return 0 if result.verdict.ok else EXIT_DIFFERS


def cmd_info(args):
    """Print what a bag holds, like ros2 bag info."""
    from microball_ros.io.bags.reader import open_bag

    for line in open_bag(args.bag).info_lines():
        print(line)
    return 0


def cmd_reindex(args):
    """Rebuild a bag's summary and metadata.yaml after its recorder died."""
    from microball_ros.io.bags.reader import reindex

    counts = reindex(args.bag)
    for topic in sorted(counts):
        print(f'{topic}: {counts[topic]} messages recovered')
    return 0


def build_parser():
    """Build the argument parser of every sub-command."""
    from microball_ros.core.bench import scenario_names

    parser = _Parser(
        prog='microball',
        description='Measure and model dynamic friction in MEMS microball bearings '
                    '(Tan, Modafe and Ghodssi, ACC 2005) on ROS 2.')
    commands = parser.add_subparsers(dest='command', metavar='COMMAND', required=True,
                                     parser_class=_Parser)

    simulate = commands.add_parser(
        'simulate', help='positions from the bench model, no camera',
        description='Simulate the crank-slider rig and write stator and slider positions.')
    simulate.add_argument('--scenario', default='paper',
                          help=f'scenario preset: {", ".join(scenario_names())} (default: paper)')
    simulate.add_argument('--duration', type=_positive_float, default=20.0,
                          help='seconds of steady oscillation to record (default: 20)')
    simulate.add_argument('--output', required=True, help='position CSV to write')
    simulate.add_argument('--seed', type=int, default=None, help='noise seed (default: preset)')
    simulate.add_argument('--no-ground-truth', dest='ground_truth', action='store_false',
                          help='omit the true_* columns')
    simulate.set_defaults(func=cmd_simulate)

    experiment = commands.add_parser(
        'experiment', help='run the whole rig as ROS 2 nodes (simulated by default)',
        description='Start servo_commander, bench_simulator, camera_tracker, '
                    'three_stage_estimator and friction_identifier as separate processes, '
                    'run the scenario, and print the identified friction model.')
    experiment.add_argument('--scenario', default='paper', help='scenario (default: paper)')
    experiment.add_argument('--duration', type=_positive_float, default=40.0,
                            help='simulated seconds (default: 40)')
    experiment.add_argument('--speed', type=_positive_float, default=1.0,
                            help='simulation speed factor; != 1 publishes /clock and the '
                                 'nodes use sim time (default: 1, real time)')
    experiment.add_argument('--output', help='bag directory to record every topic into')
    experiment.add_argument('--params', metavar='FILE',
                            help="ROS 2 parameters file (config/microball.yaml's form); its "
                                 "values override the scenario's per node")
    experiment.add_argument('--domain-id', type=int, metavar='N',
                            help='ROS domain to run in (default: a free one; one another '
                                 'microball run holds is refused)')
    experiment.set_defaults(func=cmd_experiment)

    record = commands.add_parser(
        'record', help='record topics into a rosbag2 MCAP bag',
        description='Record topics (all, or the ones named) as serialized messages into a '
                    'rosbag2 bag directory (metadata.yaml + .mcap) until Ctrl-C.')
    record.add_argument('--output', required=True, help='bag directory to create')
    record.add_argument('--topics', nargs='+', metavar='T', help='topics (default: all)')
    record.add_argument('--duration', type=_positive_float, help='stop after S wall seconds')
    record.set_defaults(func=cmd_record)

    play = commands.add_parser(
        'play', help="publish a bag's messages",
        description='Publish the recorded messages in recorded order with their recorded QoS.')
    play.add_argument('bag', help='bag directory or .mcap file')
    play.add_argument('--rate', type=_positive_float, default=1.0, help='speed (default: 1)')
    play.add_argument('--clock', action='store_true', help='publish /clock from bag time')
    play.add_argument('--loop', action='store_true', help='start again at the end')
    play.add_argument('--topics', nargs='+', metavar='T', help='topics (default: all)')
    play.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                      help='skip the first S seconds of the bag')
    play.add_argument('--lockstep', action='store_true',
                      help='publish each message only after every matched reliable '
                           'subscriber acknowledged the previous one')
    play.set_defaults(func=cmd_play)

    again = commands.add_parser(
        'reprocess', help='replay a bag through fresh nodes and compare with its outputs',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Replay the bag's /tracking/positions (or, if it has only camera frames, "
                    'its /camera/image_raw through a fresh camera_tracker) lock-step through '
                    'fresh three_stage_estimator and friction_identifier processes, record '
                    'their outputs, and compare them with the recorded ones.',
        epilog='The last line printed is the verdict on /estimation/derivatives and '
               '/friction/model\n(and /tracking/positions when frames were tracked):\n'
               '  byte-identical     every message has the recorded bytes (same platform)\n'
               '  within tolerance   decoded field by field, every number within relative '
               '1e-9 of the\n'
               '                     recorded one, every boolean, string, integer and '
               'message count\n'
               '                     identical (another platform; the largest difference '
               'is named)\n'
               '  differs: ...       the first difference: topic, message (from 0), field, '
               'both values\n'
               '  not compared: ...  the bag has none of those topics (e.g. only frames)\n'
               'Relative difference: |a-b| / max(|a|, |b|, 1e-3 x the largest magnitude of '
               'the field in\nthe topic); NaN equals NaN. Unless byte-identical, the lines '
               'before name the fields of\nthe platform fingerprints (recorded, current) '
               'that differ.\n'
               f'Exit status: 0 byte-identical, within tolerance or not compared, '
               f'{EXIT_DIFFERS} differs,\n'
               f'{EXIT_BAD_INPUT} an unusable bag, 1 a node crashed or a bug.')
    again.add_argument('bag', help='bag directory or .mcap file')
    again.add_argument('--output', required=True, help='bag directory to create')
    _frame_tracking_arguments(again)
    again.set_defaults(func=cmd_reprocess)

    info = commands.add_parser('info', help='what a bag holds (like ros2 bag info)',
                               description='Print the files, duration and topics of a bag.')
    info.add_argument('bag', help='bag directory or .mcap file')
    info.set_defaults(func=cmd_info)

    reindex = commands.add_parser(
        'reindex', help='repair a bag whose recorder died',
        description='Rebuild the summary and metadata.yaml of a bag from its complete chunks '
                    '(the original files are kept beside the bag, in BAG.truncated/).')
    reindex.add_argument('bag', help='bag directory')
    reindex.set_defaults(func=cmd_reindex)

    analyze = commands.add_parser(
        'analyze', help='three-stage estimation, memory test and friction fit',
        description='Analyse a position CSV or a bag: velocity and acceleration, memory test, '
                    'Langevin friction model and its validation by simulation.')
    analyze.add_argument('input', help='position CSV (time,stator_position,slider_position), '
                                       'bag directory or .mcap file')
    analyze.add_argument('--epsilon', type=_fraction, default=None,
                         help="the paper's fixed amplitude-filter threshold, fraction of the "
                              'largest FFT component (default: a noise-adaptive threshold, 4 '
                              "times the spectrum's noise floor)")
    analyze.add_argument('--fit-epsilon', type=_fraction, default=0.0,
                         help='amplitude-filter threshold of the accelerations the Langevin '
                              'model is fitted to (three-stage only; default: 0, see README)')
    analyze.add_argument('--exposure', type=_fraction, default=None, metavar='S',
                         help='camera exposure time, s: the three-stage method undoes the '
                              'averaging of each frame over it (default: what a bag recorded '
                              'for its estimator, else 0, instantaneous)')
    analyze.add_argument('--method', default='three-stage',
                         choices=['three-stage', 'forward', 'lowpass-forward'],
                         help='derivative estimator (default: three-stage)')
    analyze.add_argument('--json', help='write the results as JSON to this file')
    analyze.add_argument('--report', help='write figures and estimates.csv into this folder')
    _frame_tracking_arguments(analyze)
    analyze.set_defaults(func=cmd_analyze)

    track = commands.add_parser(
        'track', help='track the slider and stator marks in a video',
        description='Track the etched marks of the slider and the stator through a video (or '
                    'a folder of images) and write their positions; a lost mark leaves its '
                    'cell empty.')
    track.add_argument('video', help='video file any OpenCV build reads, or a folder of images')
    track.add_argument('--slider-roi', type=_roi, required=True, metavar='X,Y,W,H',
                       help='region of the slider mark over its whole travel, px')
    track.add_argument('--stator-roi', type=_roi, required=True, metavar='X,Y,W,H',
                       help='region of the stator mark over its whole travel, px')
    track.add_argument('--meters-per-pixel', type=float, required=True, metavar='M',
                       help='image scale along the bearing axis, m/px')
    track.add_argument('--fps', type=_positive_float, default=None,
                       help="frame rate (default: the video's own)")
    track.add_argument('--exposure', type=_positive_float, default=None,
                       help='exposure time, s, for the mid-exposure stamps (default: half '
                            'the frame period)')
    track.add_argument('--polarity', choices=['auto', 'dark', 'bright'], default='auto',
                       help='marks darker or brighter than their plate (default: auto, '
                            'learned from the video)')
    track.add_argument('--black-level', type=_non_negative_float, default=0.0, metavar='DN',
                       help="the camera's dark offset, the value of a pixel that gets no "
                            'light (default 0: estimated from the shadow): a shadow passing '
                            'over a mark is divided out above it')
    track.add_argument('--gamma', type=_gamma, default=0.0, metavar='auto|G',
                       help="the camera's encoding gamma: frames are decoded to linear light "
                            'first (1: a linear camera, as machine-vision cameras are; about '
                            '2.2 for sRGB video from consumer cameras and webcams; 0.2 .. 5). '
                            "Default 'auto': found from the first frames (the marks' "
                            'deficits shrink with their smear if encoded), else 1')
    track.add_argument('--method', choices=['auto', 'template'], default='auto',
                       help="'auto' (default): the mark's contrast centroid on a plain "
                            'plate; on a textured plate (found on the first frames) the plate '
                            "learned from the video, registered per frame; 'template': a "
                            'template of the mark learned from the video (experimental, '
                            'slower)')
    track.add_argument('--output', help='position CSV to write (time, positions, quality, '
                                        'sigma)')
    track.add_argument('--preview', metavar='FILE.png',
                       help='draw ROIs, learned marks and track on a frame into this PNG; '
                            'without --output only the first --preview-frames are tracked')
    track.add_argument('--preview-frames', type=int, default=90, metavar='N',
                       help='frames tracked for a preview without --output (default 90)')
    track.set_defaults(func=cmd_track)

    render = commands.add_parser(
        'render', help='render the simulated rig to a video (for track)',
        description='Simulate the rig and film it with the synthetic camera (motion blur, '
                    'noise, uneven light).')
    render.add_argument('--scenario', default='paper', help='scenario preset (default: paper)')
    render.add_argument('--duration', type=_positive_float, default=10.0,
                        help='seconds of video (default: 10)')
    render.add_argument('--output', required=True, help='video file to write (.mkv, .avi)')
    render.add_argument('--seed', type=int, default=None, help='noise seed (default: preset)')
    render.add_argument('--lossy', dest='lossless', action='store_false',
                        help='MJPG instead of the lossless FFV1')
    render.set_defaults(func=cmd_render)
    return parser


def _refuse(command, message):
    """Print a user's error as one line on stderr and return the bad-input exit status."""
    message = ' '.join(message.split()) or 'error'
    print(f'microball {command}: error: {message}', file=sys.stderr)
    return EXIT_BAD_INPUT


def main(argv=None):
    """Run the microball command line; return the exit status.

    A MicroballError (bad input, an unusable bag, a failed fit) or an OSError about a named file
    is one line on stderr and exit status 2; anything else is a bug: its traceback, exit 1.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except MicroballError as error:
        _progress.drop()
        return _refuse(args.command, str(error))
    except OSError as error:
        if error.filename is None:  # not about a file the user named: a bug
            raise
        _progress.drop()
        return _refuse(args.command, f'{error.filename}: {error.strerror or error}')
    except KeyboardInterrupt:
        _progress.drop()
        print(f'microball {args.command}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        _progress.drop()


if __name__ == '__main__':
    sys.exit(main())
