"""
``reducer-twin simulate``: simulated joints as a rosbag2 bag, with their ground truth.

Writes a bag directory as ``ros2 bag record -s mcap`` would have recorded the
``joint_simulator`` node: ``metadata.yaml`` (version 9) beside ``<name>_0.mcap``, profile
``ros2``, ``ros2msg`` schemas, ``cdr`` messages, QoS and type hash per channel.
``/joint_states`` carries ``<joint>`` and ``<joint>_motor`` per tick (``--layout split``:
the motor side on ``/motor_states``), ``/reducer_twin/<joint>/ground_truth`` the hidden
truth every stream second. ``--hours`` of wear exposure are compressed into
``hours·3600/aging_factor`` seconds of stream; the aging factor is stored in the bag's
``custom_data``, so ``reducer-twin analyze`` applies it without being told.
``--robot NAME --start-hours H`` continues the same joints' life (same seed) from hour H,
so consecutive bags join exactly; both are stored in ``custom_data`` for the fleet store.
The life before hour H is replayed (at most 3e9 samples, some minutes); ``--start-wear-um W``
meets the joints at wear W instead (one for all or one per joint), their life before not
simulated (a used unit recorded in real time, at aging factor 1).

The size of the bag is estimated before anything is written; above ``--max-size`` (default
5 GB) or the free space of the device the request is refused with the estimate. The bag is
written into a temporary beside BAG and renamed into place when complete.
"""

import argparse
import math
import re
import time

from reducer_twin.commands.common import print_json
from reducer_twin.core.errors import InvalidParameter


def _scales(text):
    try:
        values = tuple(float(x) for x in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f'expected a number or numbers separated by commas, got {text!r}') from None
    return values


DEFAULT_MAX_SIZE = 5_000_000_000
"""Default of ``--max-size`` [bytes]: 5 GB, about 30 M ticks of one joint."""

_UNITS = {'': 1, 'b': 1, 'k': 1e3, 'kb': 1e3, 'm': 1e6, 'mb': 1e6, 'g': 1e9, 'gb': 1e9,
          't': 1e12, 'tb': 1e12, 'kib': 2**10, 'mib': 2**20, 'gib': 2**30, 'tib': 2**40}


def _size(text):
    match = re.fullmatch(r'\s*([0-9.]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*', text)
    unit = match.group(2).lower() if match else None
    try:
        value = float(match.group(1)) * _UNITS[unit] if match else None
    except (KeyError, ValueError):
        value = None
    if value is None or not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(
            f"expected a size > 0 in bytes, or with k, M, G or T (e.g. '20G'), got {text!r}")
    return int(value)


def add_parser(sub):
    """Register the subcommand."""
    p = sub.add_parser('simulate', help='simulated joints as a rosbag2 MCAP bag with truth',
                       description=__doc__)
    p.add_argument('--out', required=True, metavar='BAG',
                   help='bag directory to create (must not exist or be empty)')
    p.add_argument('--hours', type=float, default=1000.0,
                   help='operating hours of wear exposure (default 1000)')
    p.add_argument('--aging-factor', type=float, default=3600.0,
                   help='exposure seconds per stream second (default 3600: 1 h per s)')
    p.add_argument('--joints', type=int, default=1, help='number of joints, 1 .. 12 (default 1)')
    p.add_argument('--rate-hz', type=float, default=1000.0,
                   help='JointState rate [Hz] (default 1000)')
    p.add_argument('--seed', type=int, default=0, help='noise seed of joint 1; joint k: seed+k-1')
    p.add_argument('--robot', default='', metavar='NAME',
                   help="robot name stored in the bag's custom_data (for analyze --store)")
    p.add_argument('--start-hours', type=float, default=0.0, metavar='H',
                   help='operating hours at the first sample: continues the life of the same '
                        'seed from hour H (default 0)')
    p.add_argument('--start-wear-um', type=_scales, default=(0.0,), metavar='W[,W...]',
                   help='combined wear at the first sample [um], 0 .. 100, one for all joints '
                        'or one per joint: a used unit met at that wear, its life before not '
                        'simulated (default 0)')
    p.add_argument('--wear-rate-scale', type=_scales, default=(1.0,), metavar='K[,K...]',
                   help='hidden Archard-rate multiplier, one for all joints or one per joint '
                        '(default 1)')
    p.add_argument('--profile', choices=('robot', 'paper'), default='robot',
                   help="joint motion: 'robot' cycle (default) or the paper's 90 deg/s")
    p.add_argument('--layout', choices=('combined', 'split'), default='combined',
                   help="'combined': one /joint_states; 'split': motor side on /motor_states")
    p.add_argument('--load-torque-nm', type=float, default=None,
                   help='gravity-load amplitude [N*m] (default 0.6 x rated, 470 N*m)')
    p.add_argument('--compression', choices=('none', 'zstd', 'lz4'), default='none',
                   help="MCAP chunk compression (default 'none', as ros2 bag record)")
    p.add_argument('--overwrite', action='store_true',
                   help='replace a bag that reducer-twin wrote in --out (nothing else is '
                        'ever replaced)')
    p.add_argument('--max-size', type=_size, default=DEFAULT_MAX_SIZE, metavar='SIZE',
                   help='refuse, before writing anything, a bag estimated larger than SIZE '
                        "(bytes, or with k, M, G, T; default '5G')")
    p.add_argument('--json', action='store_true',
                   help='print {"joints": {name: {true_wear_um, true_rul_h, '
                        'wear_rate_scale}}, "messages": N}')
    p.set_defaults(run=run)


def run(args):
    """Validate the request, simulate, write the bag and print the summary."""
    from reducer_twin.io.bag_writer import foreign_bag_entries
    from reducer_twin.io.outputs import check_target, DiskFull, free_bytes, human_bytes
    from reducer_twin.io.outputs import no_empty_dirs_left
    from reducer_twin.analysis.simulate import estimated_bytes, SimulationSpec, simulate_bag
    if args.seed < 0:
        raise InvalidParameter(f'--seed must be a whole number >= 0, got {args.seed}')
    spec = SimulationSpec(hours=args.hours, aging_factor=args.aging_factor, joints=args.joints,
                          rate_hz=args.rate_hz, seed=args.seed,
                          wear_rate_scales=args.wear_rate_scale, profile=args.profile,
                          layout=args.layout, load_torque_nm=args.load_torque_nm,
                          compression=args.compression, start_hours=args.start_hours,
                          robot=args.robot, start_wear_um=args.start_wear_um)
    check_target(args.out, foreign_bag_entries, '--out', args.overwrite,
                 'a bag written by reducer-twin')
    needed = estimated_bytes(spec)
    if needed > args.max_size:
        raise InvalidParameter(
            f'--hours {spec.hours:g} at --aging-factor {spec.aging_factor:g}, {spec.joints} '
            f'joint(s) at --rate-hz {spec.rate_hz:g} would write about {human_bytes(needed)} '
            f'({spec.messages:,} ticks), more than --max-size {human_bytes(args.max_size)}; '
            'raise --max-size, or ask for fewer hours or joints, a lower rate or a higher '
            'aging factor')
    free = free_bytes(args.out)
    if free is not None and needed > free:
        raise DiskFull(f'the simulated bag --out {args.out} needs about {human_bytes(needed)} '
                       f'({needed:,} bytes), but only {human_bytes(free)} ({free:,} bytes) are '
                       'free on its device; nothing was written')
    start = time.perf_counter()
    with no_empty_dirs_left([args.out]):
        result = simulate_bag(args.out, spec, overwrite=args.overwrite)
    seconds = time.perf_counter() - start
    if args.json:
        print_json(result.as_json())
        return 0
    span = f' (hours {spec.start_hours:,g} .. {spec.start_hours + spec.hours:,g}' + (
        f' of robot {spec.robot})' if spec.robot else ')') if spec.start_hours or spec.robot \
        else ''
    print(f'wrote {result.path}: {result.messages:,} JointState messages, {spec.joints} '
          f'joint(s), {result.stream_s:,.1f} s of stream = {spec.hours:,g} h{span} at aging '
          f'factor {spec.aging_factor:g}, in {seconds:.2f} s ({result.messages / seconds:,.0f} '
          'msg/s)')
    for name, truth in result.truth.items():
        print(f'  {name}: true wear {truth["true_wear_um"]:.3f} um, true remaining life '
              f'{truth["true_rul_h"]:,.0f} h, wear-rate scale {truth["wear_rate_scale"]:g}')
    return 0
