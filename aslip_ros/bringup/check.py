"""``aslip check <what>``: the bring-up checks of a new cell (docs/bringup.md).

- ``audio``: list the inputs, or record a few seconds and judge each channel's level;
- ``taps``: tap each pad when prompted; is the channel order the one named?
- ``mocap``: rate, jitter, dropouts and latency of the finger and object poses (ROS;
  PoseStamped topics, or two bodies of a mocap4r2 RigidBodies);
- ``grasp-plane``: ``grasp_plane_in_finger`` from a recording of the object held still;
- ``grasp-axes``: the grasp plane's orientation in the finger body, from a sweep of the arm,
  written into the cell file;
- ``arm``: the xArm's connection, and a 1 cm move at 1 cm/s inside the limits;
- ``realtime``: does the live inference keep its 10 ms hop, with margin, on this machine?

Each prints one verdict line and exits 0 (OK) or 1 (FAIL).
"""

from __future__ import annotations

import argparse
import os
import sys

from aslip_ros.bringup import levels as lv

WHAT = ('audio', 'taps', 'mocap', 'grasp-plane', 'grasp-axes', 'arm', 'realtime')


class _Help(argparse.ArgumentDefaultsHelpFormatter):
    """Shows a default only where there is one and the help does not state it already."""

    def _get_help_string(self, action):
        text = action.help or ''
        if action.default in (None, False) or 'default' in text:
            return text
        return super()._get_help_string(action)


def _names(text: str) -> list:
    names = [n.strip() for n in text.split(',')]
    if not all(names):
        raise argparse.ArgumentTypeError(f'empty channel name in {text!r}')
    return names


def _audio_source_args(p: argparse.ArgumentParser, required: bool) -> None:
    src = p.add_mutually_exclusive_group(required=required)
    src.add_argument('--device', help='PortAudio input: index or (part of the) name')
    src.add_argument('--wav', help='a recording instead of a device (replayed unpaced)')
    ch = p.add_mutually_exclusive_group()
    ch.add_argument('--channels', type=int, help='channels to open (default: all inputs of '
                    'the device)')
    ch.add_argument('--channel-names', type=_names, metavar='A,B,..',
                    help='one name per channel, in input order (sets the count)')
    p.add_argument('--sample-rate', type=float, metavar='HZ',
                   help="sample rate (default: the device's default rate)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The check subcommands and their options."""
    fmt = _Help
    sub = parser.add_subparsers(dest='what', metavar='<what>', required=True)

    p = sub.add_parser('audio', formatter_class=fmt, help='list the audio inputs, or record '
                       'one and show per-channel level, clipping, DC and a verdict')
    _audio_source_args(p, required=False)
    p.add_argument('--seconds', type=float, default=3.0, help='how long to record [s]')
    p.add_argument('--silent-dbfs', type=float, default=lv.DEFAULT_SILENT_DBFS,
                   help='a channel quieter than this (RMS) is SILENT')
    p.add_argument('--max-dc', type=float, default=lv.DEFAULT_MAX_DC,
                   help='a mean beyond this (fraction of full scale) is a DC offset')

    p = sub.add_parser('taps', formatter_class=fmt, help='tap each pad when prompted: '
                       'checks that the channels come in the named order')
    _audio_source_args(p, required=True)
    p.add_argument('--taps-per-pad', type=int, default=3, help='taps asked of each pad')
    p.add_argument('--seconds-per-pad', type=float, default=4.0,
                   help='each pad is prompted for this long, one after the other')
    p.add_argument('--timeout-s', type=float, default=20.0,
                   help='give up when the device delivers no audio for this long [s]')

    p = sub.add_parser('mocap', formatter_class=fmt, help='rate, jitter, dropouts and '
                       'latency of the finger and object poses (ROS 2)')
    _pose_source(p)
    p.add_argument('--seconds', type=float, default=5.0, help='how long to listen [s]')

    p = sub.add_parser('grasp-plane', formatter_class=fmt, help='grasp_plane_in_finger '
                       'from a recording of the object held still in the grasp')
    p.add_argument('bag', help='rosbag2 directory or .mcap file')
    _pose_source(p)
    from aslip_ros.bringup.grasp_plane import DEFAULT_MAX_SPREAD_M
    p.add_argument('--max-spread-m', type=float, default=DEFAULT_MAX_SPREAD_M,
                   help='the object counts as still within this distance [m]')
    p.add_argument('--orientation', type=float, nargs=4, metavar=('QX', 'QY', 'QZ', 'QW'),
                   default=[0.0, 0.0, 0.0, 1.0],
                   help='the grasp plane\'s orientation in the finger frame (not measured '
                   'here: aslip check grasp-axes measures it)')

    p = sub.add_parser('grasp-axes', formatter_class=fmt, help='the grasp plane\'s '
                       'orientation in the finger body, measured by moving the arm along the '
                       'TCP\'s grasp-plane axes; written into the cell file')
    from aslip_ros.bringup.grasp_axes import add_arguments as grasp_axes_arguments
    grasp_axes_arguments(p)

    p = sub.add_parser('arm', formatter_class=fmt, help='the xArm connection and a 1 cm '
                       'move at 1 cm/s and back, inside the limits')
    _arm_args(p)

    p = sub.add_parser('realtime', formatter_class=fmt, help='time the live inference of '
                       'each model on simulated audio: does it keep its 10 ms hop with margin?')
    _realtime_args(p)


def _realtime_args(p: argparse.ArgumentParser) -> None:
    from aslip_ros.bringup import realtime as rt
    p.add_argument('--checkpoint', action='append', metavar='PATH',
                   help='a checkpoint to time (repeatable; default: the shipped models, '
                   + ', '.join(rt.DEFAULT_CHECKPOINTS) + ')')
    p.add_argument('--duration', type=float, default=rt.DEFAULT_DURATION_S,
                   help='seconds of audio timed per model [s]')
    p.add_argument('--margin', type=float, default=rt.DEFAULT_MARGIN,
                   help='OK when the p99 per hop is at most this fraction of the hop')
    p.add_argument('--max-cores', type=float, default=rt.DEFAULT_MAX_CORES,
                   help='OK when the inference needs at most this many cores at real time')
    p.add_argument('--hop', type=float, default=0.01, help='hop (and audio block) [s]')
    p.add_argument('--threads', type=int, default=rt.DEFAULT_THREADS,
                   help='torch threads (slip_inference\'s torch_threads)')
    p.add_argument('--json', metavar='PATH', help='also write the figures here (JSON)')


def _pose_source(p: argparse.ArgumentParser) -> None:
    from aslip_ros.bringup import mocap_source
    p.add_argument('--setup', metavar='FILE', help='the cell file: its mocap_bridge section '
                   'names the pose topics, or (pose_source: rigid_bodies) the RigidBodies '
                   'topic and bodies (options override it)')
    mocap_source.add_arguments(p)


def _mocap_source(args: argparse.Namespace):
    from aslip_ros.bringup.mocap_source import resolve
    from aslip_ros.cell import load_cell
    return resolve(args, load_cell(args.setup) if args.setup else None)


def _arm_args(p: argparse.ArgumentParser) -> None:
    from aslip_ros.bringup.arm_check import AXES
    p.add_argument('--ip', help='xArm controller IP (default: the --setup file\'s xarm_ip)')
    p.add_argument('--setup', metavar='FILE', help='the cell file: its arm section gives the '
                   'IP, the speed limit and the workspace (flags override it)')
    p.add_argument('--speed', type=float, default=0.01, help='test speed [m/s]')
    p.add_argument('--distance', type=float, default=0.01, help='test distance [m]')
    p.add_argument('--axis', choices=sorted(AXES), help='move along this axis only '
                   '(default: +z, else the first axis with room)')
    p.add_argument('--workspace-min', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   help='workspace lower corner [m] (default: the XArmConfig default)')
    p.add_argument('--workspace-max', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   help='workspace upper corner [m] (default: the XArmConfig default)')
    p.add_argument('--max-speed', type=float, metavar='M_S',
                   help='TCP speed limit [m/s] (default: the XArmConfig default)')
    p.add_argument('--yes', action='store_true', help='move without asking')


def _confirm(question: str) -> bool:
    if not sys.stdin.isatty():
        print(f'{question} [y/N] (no terminal: pass --yes)', flush=True)
        return False
    return input(f'{question} [y/N] ').strip().lower() in ('y', 'yes')


def run(args: argparse.Namespace) -> int:
    """Run the chosen check; 0 on OK, 1 on FAIL."""
    out = sys.stdout
    if args.what in ('audio', 'taps'):
        from aslip_ros.bringup import audio_checks as ac
        if args.what == 'audio' and args.device is None and args.wav is None:
            return ac.list_inputs(out)
        source = ac.open_source(args.device, args.wav, args.channels, args.channel_names,
                                args.sample_rate)
        if args.what == 'audio':
            return ac.check_audio(source, args.seconds, out, args.silent_dbfs, args.max_dc)
        return ac.check_taps(source, out, args.taps_per_pad, args.seconds_per_pad,
                             args.timeout_s)
    if args.what == 'mocap':
        return _mocap(args, out)
    if args.what == 'realtime':
        return _realtime(args, out)
    if args.what == 'grasp-axes':
        from aslip_ros.bringup.grasp_axes import run as grasp_axes
        return grasp_axes(args, out, (lambda q: True) if args.yes else _confirm)
    if args.what == 'grasp-plane':
        from aslip_ros.bringup.grasp_plane import check_grasp_plane
        return check_grasp_plane(args.bag, _mocap_source(args), out, args.max_spread_m,
                                 args.orientation)
    from aslip_ros.bringup.arm_check import check_arm
    config = _arm_config(args)
    return check_arm(config, args.speed, args.distance, args.axis, out,
                     (lambda q: True) if args.yes else _confirm)


def _arm_config(args: argparse.Namespace):
    """The XArmConfig from the flags, else the cell file's arm section, else the config's
    own defaults."""
    from aslip_ros.bringup.arm_check import arm_config
    cell = {}
    if args.setup:
        from aslip_ros.cell import load_cell
        cell = load_cell(args.setup).section('arm')

    def pick(flag, key):
        value = cell.get(key) if flag is None else flag
        return None if value is None or (isinstance(value, list) and not value) else value

    ip = pick(args.ip, 'xarm_ip')
    if not ip:
        raise ValueError('--ip is needed (the xArm controller\'s address), or a --setup file '
                         'whose arm section has xarm_ip')
    return arm_config(str(ip), pick(args.max_speed, 'arm_max_speed_m_s'),
                      pick(args.workspace_min, 'arm_workspace_min_m'),
                      pick(args.workspace_max, 'arm_workspace_max_m'))


def _realtime(args: argparse.Namespace, out) -> int:
    from aslip_ros.bringup import realtime as rt
    paths = args.checkpoint or rt.default_checkpoints()
    rt.verdict([], args.margin, args.max_cores)         # refuses bad options before timing
    ckpts = [rt.load(p) for p in paths]                 # and every unusable checkpoint

    def start(name: str) -> None:
        print(f'timing {name} for {args.duration:g} s of audio...', file=out, flush=True)

    reports = []
    for path, ckpt in zip(paths, ckpts):
        r = rt.measure(ckpt, args.duration, args.hop, args.threads, on_start=start,
                       source=str(path))
        reports.append(r)
        print(r.text(), file=out, flush=True)
    for r in reports:
        print(rt.model_line(r, args.margin, args.max_cores), file=out)
    verdict = rt.verdict(reports, args.margin, args.max_cores)
    cores = os.cpu_count() or 1
    workers = rt.demo_workers(reports, cores)
    verdict.notes.append(rt.workers_line(workers, reports, cores))
    if args.json:
        from aslip_ros.util import write_json
        write_json(args.json, {'margin': args.margin, 'max_cores': args.max_cores,
                               'cpus': cores, 'load_average': list(os.getloadavg()),
                               'models': [r.to_dict() for r in reports],
                               'ok': verdict.ok, 'problems': verdict.problems,
                               'demo_workers': workers})
    return verdict.report(out)


def _mocap(args: argparse.Namespace, out) -> int:
    from aslip_ros.bringup.mocap_stats import mocap_verdict, stream_stats
    from aslip_ros.nodes.mocap_check import record, record_bodies
    source = _mocap_source(args)
    missing = ''
    print(f'listening to {source.text()} for {args.seconds:g} s...', file=out, flush=True)
    if source.rigid:
        samples, missing = record_bodies(source.rigid_bodies_topic, source.bodies,
                                         args.seconds)
    else:
        samples = record(list(source.topics.values()), args.seconds)
    stats = {t: stream_stats(t, *s) for t, s in samples.items()}
    for s in stats.values():
        print(s.text(), file=out)
    return mocap_verdict(stats, missing_bodies=missing).report(out)
